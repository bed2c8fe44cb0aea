from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.sim.field import FIELD_SCENARIOS
from common.yaw import Provenance
from services.tools.bench import _runner, yaw, yaw_field
from services.tools.bench.yaw_field import _Series, pair_stats

FIELDS = {
    "pairs",
    "median_abs_err_deg",
    "p99_abs_err_deg",
    "pairs_over_5deg",
    "max_ame_deg",
    "final_err_deg",
    "ms_median",
    "ms_p99",
    "bridged_pairs",
    "held_pairs",
    "unmeasured_over_2deg",
    "unmeasured_max_err_deg",
}
#: what the core adds (it publishes variances): its measured pairs' and its integrated yaw's consistency
CORE_SCORES = {"measured_within_2_sigma", "measured_mean_nees", "yaw_within_2_sigma", "yaw_mean_nees"}


def test_pair_stats_counts_errors_of_the_published_deltas() -> None:
    truth = np.cumsum(np.full(150, math.radians(1.0)))
    deltas = list(np.diff(truth))
    deltas[40] += math.radians(90.0)  # one 90 deg jump, then corrected: the integrated yaw is off in between
    deltas[41] -= math.radians(90.0)
    provenance = [Provenance.MEASURED] * 149
    provenance[40], provenance[41], provenance[60] = Provenance.HELD, Provenance.BRIDGED, Provenance.HELD
    stats = pair_stats(_Series(deltas, [1.0] * 149, bridged=3, provenance=provenance), truth)
    assert set(stats) == FIELDS
    assert stats["pairs"] == 149 and stats["pairs_over_5deg"] == 2 and stats["bridged_pairs"] == 3
    assert stats["max_ame_deg"] > 0.5 and abs(stats["final_err_deg"]) < 1e-9
    # the two jumps were held/bridged pairs: both over 2 deg; the third held pair was right
    assert stats["held_pairs"] == 2 and stats["unmeasured_over_2deg"] == 2
    assert stats["unmeasured_max_err_deg"] == pytest.approx(90.0)


def test_pair_stats_score_the_measured_pairs_against_their_published_variance() -> None:
    """The core publishes a variance with each delta: the measured pairs' share within 2 sigma and mean
    NEES (the held and bridged pairs are not measurements), and with the integrated yaw: its error at every
    frame against it; the baseline publishes none and has no such fields."""
    truth = np.zeros(101)
    errors = np.tile([0.001, -0.003], 50)  # published sigma 0.001: NEES 1 and 9 in turn
    provenance = [Provenance.MEASURED] * 100
    provenance[1] = Provenance.BRIDGED  # a pair at NEES 9 that is not a measurement
    # the integrated yaw's error walks off by -0.002 rad every two pairs: 0.001, -0.002, -0.001, -0.004, ...
    yaw_variance = [4.41e-6] * 50 + [1e-6] * 50  # sigma 0.0021, then 0.001
    series = _Series(list(errors), [1.0] * 100, 1, provenance, [1e-6] * 100, yaw_variance)
    stats = pair_stats(series, truth)
    assert set(stats) == FIELDS | CORE_SCORES
    assert stats["measured_within_2_sigma"] == pytest.approx(50 / 99)
    assert stats["measured_mean_nees"] == pytest.approx((50 * 1.0 + 49 * 9.0) / 99)
    yaw_error = np.cumsum(errors)
    expected = yaw_error**2 / np.asarray(yaw_variance)
    assert stats["yaw_mean_nees"] == pytest.approx(float(np.mean(expected)))
    assert stats["yaw_within_2_sigma"] == pytest.approx(0.05)  # the first five, within 0.0042
    assert set(pair_stats(_Series(list(errors), [1.0] * 100), truth)) == FIELDS


def test_bench_yaw_field_suite_refuses_an_unknown_scenario() -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    with pytest.raises(yaw.CapatazError, match="nowhere"):
        yaw.run(parser.parse_args(["--suite", "field", "--field-scenarios", "field,nowhere"]))


def test_bench_yaw_field_suite_refuses_too_few_frames() -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    with pytest.raises(yaw.CapatazError):
        yaw.run(parser.parse_args(["--suite", "field", "--field-frames", "50"]))


@pytest.mark.slow
def test_bench_yaw_field_suite_writes_exactly_the_issues_fields(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One field scenario (of the suite's ten) and the hover, 102 frames each: the file's layout."""
    subset = {"checkerboard": FIELD_SCENARIOS["checkerboard"]}
    monkeypatch.setattr(yaw_field, "FIELD_SCENARIOS", subset)
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    args = parser.parse_args(["--suite", "field", "--field-frames", "102", "--hover-frames", "102"])
    args.out = tmp_path
    assert _runner(yaw)(args) == 0
    payload = json.loads((tmp_path / "yaw_field.json").read_text())
    assert set(payload) == {
        "field_size",
        "field_lens",
        "field_fps",
        "field_level",
        "scenarios",
        "baseline",
        "worst_max_ame_deg",
        "total_pairs_over_5deg",
        "total_unmeasured_over_2deg",
        "metadata",  # every bench's JSON: its command, date and commit (capataz results)
        "table",
    }
    assert {"command", "git_commit", "time_utc"} <= set(payload["metadata"]), payload["metadata"]
    names = {*subset, "hover"}
    assert set(payload["scenarios"]) == set(payload["baseline"]) == names
    assert all(set(stats) == FIELDS for stats in payload["baseline"].values())
    scored = {"pyramid_level", *CORE_SCORES}
    assert all(set(stats) == FIELDS | scored for stats in payload["scenarios"].values())
    assert payload["field_lens"] is None  # each scenario's own lens
    assert payload["field_fps"] == 20.0  # the suite's frame rate
    assert payload["field_level"] == "none"  # a master's default: the mount's fixed view
    # the core at the level a master resolves for the frames: 320x240 and the hover's 752x480 at 1
    assert payload["field_size"] == "320x240"
    assert payload["scenarios"]["checkerboard"]["pyramid_level"] == 1
    assert payload["scenarios"]["hover"]["pyramid_level"] == 1
    assert payload["total_pairs_over_5deg"] == 0


def test_bench_yaw_field_suite_refuses_an_unknown_lens(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--suite", "field", "--field-lens", "tele400"])
    assert "fisheye120" in capsys.readouterr().err  # the choices are named


@pytest.mark.parametrize("size", ["640", "640x", "wide"])
def test_bench_yaw_field_suite_refuses_a_size_that_is_not_wxh(size: str) -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    with pytest.raises(yaw.CapatazError, match="--field-size"):
        yaw.run(parser.parse_args(["--suite", "field", "--field-size", size, "--field-frames", "102"]))


@pytest.mark.parametrize("fps", ["0", "-5", "nan", "5000", "fast"])
def test_bench_yaw_field_suite_refuses_a_frame_rate_out_of_range(
    fps: str, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--suite", "field", "--field-fps", fps])
    assert "--field-fps" in capsys.readouterr().err
