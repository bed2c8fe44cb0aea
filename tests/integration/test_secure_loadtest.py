"""``capataz loadtest --secure``: two streams, a standby master each and the active one killed, under the
open and the secure profile, with the same results: every frame served once (no duplicates: one elected
master per UAV), at most one frame lost at the kill, the yaw continuous across the take-over."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from services.tools.cli import main

pytestmark = [pytest.mark.zenoh, pytest.mark.long]  # shorter: test_secure_system.py, test_loadtest_run.py


def loadtest(tmp_path: Path, profile: str) -> dict:
    cluster = tmp_path / "c.yml"
    cluster.write_text("name: small\nhosts:\n  - name: h1\n    workers: 1\n")
    args = [
        "loadtest", "--cluster", str(cluster), "--streams", "2", "--fps", "5", "--duration", "8",
        "--in-flight", "1", "--standby", "--fault", "kill:master@4s", "--slo", "lost_per_fault<=1",
        "--slo", "yaw_jump_deg<=1", "--out", str(tmp_path / "out"), "--name", profile,
    ]  # fmt: skip
    if profile == "secure":
        args += ["--secure", str(tmp_path / "secure")]
    assert main(args) == 0, profile
    return json.loads((tmp_path / "out" / f"{profile}.json").read_text())


def test_the_load_test_gives_the_same_results_open_and_secure(tmp_path: Path) -> None:
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    reports = {profile: loadtest(tmp_path, profile) for profile in ("open", "secure")}
    for profile, report in reports.items():
        assert report["profile"] == profile and report["slo_passed"]
        assert [s["uav"] for s in report["per_stream"]] == ["uav0", "uav1"]
        for stream in report["per_stream"]:
            assert stream["published"] == 40 and stream["received"] >= 39, (profile, stream)
            assert stream["duplicates"] == 0, (profile, stream)  # one elected master per UAV
        (fault,) = report["faults"]
        assert fault["hit"].startswith("master/") and fault["yaw_discontinuity_deg"] < 1.0
