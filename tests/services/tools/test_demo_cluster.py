"""`make run`'s cluster demo on a short flight: each frame has the in-process yaw; report and plots."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.dispatch import SELF
from services.tools.demo_cluster import run_demo
from tests.services.tools.test_tum_output import assert_evo_agrees

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]


def test_cluster_demo_reports_every_frame_equal_to_in_process(tmp_path: Path) -> None:
    summary = run_demo(tmp_path, n_frames=120)
    assert summary["frames_with_yaw"] == 120 and summary["frames_lost"] == 0
    assert summary["dropped_frames"] == 0  # two frames in flight never make the master drop one
    assert summary["max_abs_diff_vs_in_process_deg"] <= 1e-9
    assert summary["rms_deg"] < 1.0
    top = [r for r in summary["members"] if ">" not in r["member"]]
    assert sum(r["share"] for r in top) == pytest.approx(1.0)
    foremen = [r for r in top if r["member"] != SELF]
    assert {r["member"] for r in foremen} == {"foreman/h1/0", "foreman/h2/0"}
    assert all(r["speed_patches_s"] > 0 for r in foremen), foremen
    # the master only dispatches, but for two fallbacks: the share of a member that missed its deadline (a
    # re-dispatch, which one stall of a loaded host makes happen: CI 2 of 120), and the overflow of a member
    # held at half the frame by the trust cap when the other is over 2x slower (a loaded host's round trips)
    own = sum(r["share"] for r in top if r["member"] == SELF)
    assert own <= 0.1 or summary["redispatched"] > 0, top
    for path in summary["plots"]:
        assert Path(path).stat().st_size > 0
    assert (tmp_path / "cluster" / "yaw_cluster.json").is_file()
    assert (tmp_path / "cluster" / "yaw_cluster.png").is_file()
    assert all(code == 0 for code in summary["exit_codes"].values()), summary["exit_codes"]
    assert summary["tum"]["poses"] == 120 and summary["tum"]["ape_rotation_rmse_deg"] > 0
    assert_evo_agrees(summary["tum"])  # out/tum/yaw.tum and yaw_truth.tum


def test_a_member_without_a_measured_speed_says_so_instead_of_nan_regression() -> None:
    """Issue 28: ``make run`` printed ``nan patches/s`` for members that computed nothing themselves."""
    from services.tools.demo_cluster import member_line

    row = {
        "member": "master/master/0",
        "share": 0.0,
        "patches_per_frame": 0.0,
        "speed_patches_s": float("nan"),
    }
    assert "nan" not in member_line(row) and "no speed measured" in member_line(row)
    assert member_line({**row, "speed_patches_s": 1234.4}).endswith("1234 patches/s")
