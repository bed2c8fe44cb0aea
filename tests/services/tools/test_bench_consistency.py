"""``capataz bench consistency --quick``: every suite's lines in the file and the table, held-out seeds, the
bounds over seeds; the estimator's published covariances on a held-out seed."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.consistency import consistency as line_consistency
from common.geometry import wrap_angle_rad
from common.sim.field import field_flight
from common.sim.flight import FlightOptions
from common.yaw import YawSettings
from services.estimator.outputs import AS_FILTERED
from services.tools.bench import _runner, consistency
from services.tools.bench.consistency_runs import (
    FLIGHTS,
    GLARE_LEVEL,
    estimator_lines,
    estimator_outputs,
    localizer_samples,
    per_flight,
    two_folds,
    with_glare,
    yaw_samples,
)
from services.tools.bench.yaw_field import run_core


@pytest.mark.slow
def test_bench_consistency_quick_writes_every_suites_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    args = parser.parse_args(["--quick"])
    args.out = tmp_path
    assert _runner(consistency)(args) == 0
    payload = json.loads((tmp_path / "consistency.json").read_text())
    assert payload["fit_seeds"] == [0] and payload["held_out_seeds"] == [1]
    assert payload["settings"]["imu_hz"] == 400.0 and payload["settings"]["camera_hz"] == 20.0
    assert payload["settings"]["range_hz"] == 50.0 and payload["settings"]["frame_jitter_ms"] == 0.0
    held = payload["lines"]["held_out"]
    for line in ("yaw pair measured", "yaw accumulated gyro", "estimator attitude paper_c",
                 "estimator tilt paper_c", "estimator heading paper_c", "estimator position paper_c",
                 "localizer office tracking"):  # fmt: skip
        assert line in held, sorted(held)
        c = held[line]
        assert c["samples"] > 0
        assert 0.0 <= c["within_1_sigma"] <= c["within_2_sigma"] <= c["within_3_sigma"] <= 1.0
        assert c["nees_lower"] < c["dof"] < c["nees_upper"]
        assert c["nees_within_bounds"] == (c["nees_lower"] <= c["nees_mean"] <= c["nees_upper"])
        # one held-out seed: no step has two seeds, so no per-step test
        assert c["steps_steps"] == 0 and c["meets_steps"] is False
    # all seeds: the steps both seeds share (a step is a scenario's pair, a flight's output, a frame)
    both = payload["lines"]["all"]["estimator attitude paper_c"]
    assert both["steps_runs_median"] == 2 and both["steps_steps"] > 0
    assert both["steps_within"] + both["steps_above"] + both["steps_below"] == pytest.approx(1.0)
    assert both["meets_steps"] == (both["steps_within"] >= payload["target_steps_within"])
    # one held-out seed: its mean, no bounds over seeds; all seeds: two means and bounds between them
    measured = held["yaw pair measured"]
    assert len(measured["nees_per_seed"]) == 1 and measured["nees_seed_lower"] is None  # NaN in the file
    pooled = payload["lines"]["all"]["estimator attitude paper_c"]
    per_seed = pooled["nees_per_seed"]
    assert len(per_seed) == 2
    assert (
        min(per_seed) - 1e-9 <= pooled["nees_seed_lower"] <= pooled["nees_seed_upper"] <= max(per_seed) + 1e-9
    )
    # the figures of all seeds pool the two halves
    assert payload["lines"]["all"]["yaw pair measured"]["samples"] == (
        payload["lines"]["fit"]["yaw pair measured"]["samples"] + held["yaw pair measured"]["samples"]
    )
    assert "yaw pair measured" in capsys.readouterr().out


def test_the_estimators_flights_fly_at_the_rates_asked() -> None:
    """``--imu-hz`` / ``--camera-hz`` / ``--range-hz``: the estimator's flights are sampled at those rates;
    ``--frame-jitter-ms`` moves the frames off the IMU's samples."""
    read = per_flight(
        3, 12, ["paper_c"], lambda flight, outputs: (flight, len(outputs)),
        FlightOptions(imu_rate_hz=100.0, camera_rate_hz=10.0, range_rate_hz=33.0, frame_jitter_s=0.004),
    )  # fmt: skip
    flight, outputs = read["paper_c"]
    moved = flight.frame_stamps_s - 0.1 * np.arange(flight.n_frames)
    assert np.all(np.abs(moved) <= 0.004 + 1e-9) and np.any(np.abs(moved) > 1e-3)
    assert np.allclose(np.diff(flight.imu.stamps_s), 0.01)
    assert np.allclose(np.diff(flight.range.stamps_s), 1.0 / 33.0)
    assert outputs > 0


BAD_RATES = [
    ["--imu-hz", "0"], ["--imu-hz", "nan"], ["--camera-hz", "1000"], ["--range-hz", "0"],
    ["--frame-jitter-ms", "-1"],
]  # fmt: skip


@pytest.mark.parametrize("option", BAD_RATES)
def test_bench_consistency_refuses_a_rate_out_of_range(option: list[str]) -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(option)


def test_bench_consistency_needs_two_seeds() -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    with pytest.raises(SystemExit):
        consistency.run(parser.parse_args(["--seeds", "1", "--suites", "yaw"]))


def test_bench_consistency_takes_one_fit_at_a_time(capsys: pytest.CaptureFixture[str]) -> None:
    """Regression: ``--fit-yaw --fit-attitude`` ran the first fit and silently dropped the second."""
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--fit-yaw", "--fit-attitude"])
    assert "not allowed with argument" in capsys.readouterr().err
    assert parser.parse_args(["--fit-drift"]).fit_drift


@pytest.mark.parametrize("glare", [-0.1, 0.6, math.nan])
def test_bench_consistency_refuses_a_glare_that_is_not_a_share(glare: float) -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    args = parser.parse_args(["--suites", "yaw", "--glare", str(glare)])
    with pytest.raises(SystemExit, match="--glare"):
        consistency.run(args)


def test_glare_washes_out_about_its_share_of_the_frames_never_the_first_and_the_same_each_time() -> None:
    frames = [np.full((4, 6), i % 200, np.uint8) for i in range(2000)]
    washed = with_glare(frames, 0.08, seed=3, scenario=1)
    out = [k for k in range(len(frames)) if washed[k] is not frames[k]]
    assert all(np.all(washed[k] == GLARE_LEVEL) and washed[k].shape == (4, 6) for k in out)
    assert 0 not in out and 0.06 < len(out) / len(frames) < 0.10
    again = with_glare(frames, 0.08, seed=3, scenario=1)
    assert all(np.array_equal(a, b) for a, b in zip(washed, again, strict=True))
    assert with_glare(frames, 0.0, seed=3, scenario=1) is frames


@pytest.mark.slow
def test_glare_gives_the_mounted_rigs_bridged_and_held_pairs_lines_and_the_bridged_ones_stay_honest() -> None:
    """The gyro prior of a tilted camera once integrated the rate about its optical axis, roll included:
    the mounted rig's bridged pairs were off by tan(10 deg) of the roll in each (up to 0.068 deg, NEES
    5.8 over seeds 0-2). Washed-out frames make the core bridge (gyro) and hold (no IMU) their pairs."""
    samples = yaw_samples(seed=0, frames=60, scenarios=["mounted_rig"], glare=0.15)
    bridged, held = samples["yaw pair bridged"], samples["yaw pair held (no imu)"]
    assert len(bridged.nees) >= 5 and len(held.nees) >= 5
    # each within 3 sigma, and their mean NEES under 2 (the bug: 10.4 here, up to 27.6; fixed: 0.12, 0.9)
    assert max(bridged.nees) < 9.0 and float(np.mean(bridged.nees)) < 2.0, bridged.nees


@pytest.mark.slow
def test_held_pairs_are_published_with_their_own_variance_not_the_gates_regression() -> None:
    """The bug: a held pair (no gyro, nothing measured) was published with the gate's tolerance for a sigma
    (a third of at least 5 deg), 16 times its errors' std (mean NEES 0.004 on seeds 10-19). Seed 13 (held
    out), a fifth of the frames washed out."""
    held = yaw_samples(seed=13, frames=60, scenarios=["checkerboard", "tiles", "fast_yaw"], glare=0.2)[
        "yaw pair held (no imu)"
    ]
    scored = line_consistency(held.nees, 1)
    assert scored.samples >= 15
    assert 0.3 <= scored.nees_mean <= 3.0 and scored.within_2_sigma >= 0.85, scored


@pytest.mark.slow
def test_the_published_yaw_counts_its_pairs_correlated_errors_regression() -> None:
    """The bug: the yaw's variance summed its pairs' variances as if their errors were independent, but
    consecutive measured pairs err alike, so the published yaw was overconfident (on the held-out seeds 10-19
    its mean NEES was 5.4, 0.62 of its errors within 2 sigma). Seed 13 (held out), three of the suite's
    600-frame flights with the gyro: the yaw published now (mean NEES 1.01, 0.978 within 2 sigma), and what
    the independent sum would publish for the same pairs (5.2, 0.53). The flights were 100 frames, which
    are calmer than the suite's that the pairs' model is fitted on and claims: there the published yaw read
    1.93 with the model before the per-patch pair variances and 2.19 with them, against a bound of 2."""
    published, independent = [], []
    for name in ("checkerboard", "tiles", "fast_yaw"):
        flight = field_flight(name, seed=13, n_frames=600)
        series = run_core(flight, YawSettings(), None, True)
        error = np.cumsum(wrap_angle_rad(np.asarray(series.delta_rad) - np.diff(flight.yaw_rad)))
        published.append(error**2 / np.asarray(series.yaw_variance_rad2))
        independent.append(error**2 / np.cumsum(series.delta_variance_rad2))
    now = line_consistency(np.concatenate(published), 1)
    before = line_consistency(np.concatenate(independent), 1)
    assert before.nees_mean > 3.0 and before.within_2_sigma < 0.8  # the flights show the bug
    assert now.nees_mean < 2.0 and now.within_2_sigma >= 0.85, now


@pytest.mark.slow
def test_the_estimators_published_covariances_are_honest_on_a_held_out_seed() -> None:
    """Seed 10 (held out: the published model was fit on seeds 0-9), 600 frames of each flight: the mean
    NEES of the published tilt and position (both flights) and of the attitude and its heading (paper C's)
    is within a factor ``spread`` of its dof (the spread one seed's mean has: errors are correlated over a
    flight, so one seed is about one sample; on the fit seeds the per-seed means of the position ranged
    over about that factor). The filter's covariances as they are were too cautious on the agile flight by
    more than that (mean NEES 0.17 and 0.90).

    The agile flight's heading varies between seeds by more than the spread: over seeds 10-19 its mean NEES
    is 0.86 (bounds over seeds 0.41-1.39) since the yaw's over-read model, but seed 10's is 0.05-0.1 (its
    yaw errors are a few hundredths of a degree, below the filter's own yaw variance). So its heading is
    asserted not overconfident, and its 3-dof attitude against the tilt's dof. Paper C's heading over its
    first 300 frames (hover and the slow start, where the over-read builds up) read 0.37: the window is
    600 frames, into the turns."""
    spread = 2.5
    for name in ("paper_c", "agile"):
        flight = FLIGHTS[name](10)
        outputs = estimator_outputs(flight, 600)
        published = estimator_lines(name, flight, outputs)
        as_filtered = estimator_lines(name, flight, outputs, AS_FILTERED)
        judged = {"paper_c": (("attitude", 3), ("heading", 1)), "agile": (("attitude", 2),)}[name]
        for part, dof in (*judged, ("tilt", 2), ("position", 3)):
            line = f"estimator {part} {name}"
            nees = float(np.mean(published[line].nees))
            assert dof / spread < nees < dof * spread, (line, nees)
            if name == "agile":
                assert float(np.mean(as_filtered[line].nees)) < dof / spread, line
        if name == "agile":  # not overconfident (one seed's heading is below the spread: the docstring)
            assert float(np.mean(published[f"estimator heading {name}"].nees)) < spread
        # the altitude (1 dof): the filter's variance was too cautious (mean NEES 0.64 and 0.67 on 300
        # frames); the fit seeds' per-seed means ranged 0.81-1.12
        line = f"estimator altitude {name}"
        altitude, before = float(np.mean(published[line].nees)), float(np.mean(as_filtered[line].nees))
        assert 0.7 < altitude < 1.5 and abs(math.log(altitude)) < abs(math.log(before)), (altitude, before)


@pytest.mark.slow
def test_the_localizers_published_covariance_is_not_twice_too_cautious_on_a_held_out_office_run() -> None:
    """Regression (issue 26's localizer line): with the covariance shrunk halfway to its diagonal and not
    scaled, the office's tracked frames had a mean 6-dof NEES of 2.7-3.2 on every seed 0-19 (6 is honest):
    twice too cautious. Shrunk by 0.35 and scaled by 0.8 (fitted on seeds 0-9), 4.6-5.5 on every seed.
    Seed 12, held out; the office's per-seed means vary little (its path is the same for every seed).

    Regression too (the position and rotation blocks): shrunk by 0.35 and scaled by 0.8, the 3-dof NEES of
    the position and of the rotation block were 0.86-0.95 on the office's fit seeds (3 is honest): a reader
    of the position alone was told a variance 3 times its errors'. The diagonal times 0.32: 2.4-2.6; with the
    edge agreement (its tail of frames locked off their pose counted), 6-dof 6.1 and the blocks 3.0-3.1; with
    the fused covariance's correlations kept (the bench's error sense fixed), held-out office 6.3, 3.0-3.1."""
    samples = localizer_samples(12, 150, ["office"])
    nees = float(np.mean(samples["localizer office tracking"].nees))
    assert 4.0 < nees < 7.0, nees
    for block in ("position", "rotation"):
        nees = float(np.mean(samples[f"localizer office tracking {block}"].nees))
        assert 1.8 < nees < 4.0, (block, nees)


@given(st.lists(st.integers(0, 99), unique=True, max_size=30))
def test_a_fits_two_folds_swap_the_halves_of_its_seeds(seeds: list[int]) -> None:
    folds = two_folds(seeds)
    if len(seeds) < 2:  # a half would be empty: no check
        assert folds == []
        return
    (train, test), (train_back, test_back) = folds
    assert train + test == seeds and (train_back, test_back) == (test, train)
    assert len(train) == len(seeds) // 2
