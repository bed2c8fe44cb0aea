from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from common.errors import InputError
from common.metrics import accumulated_mean_error, yaw_error_rad, yaw_error_stats


def _eq8_loop(error: np.ndarray, n: int) -> np.ndarray:
    """Paper A eq. 8 written out literally (1-based k = 1..M-N, i = k..k+N)."""
    m = error.size
    out = []
    for k in range(1, m - n + 1):
        out.append(sum(abs(error[i - 1] - error[k - 1]) for i in range(k, k + n + 1)) / n)
    return np.array(out)


@settings(max_examples=30, deadline=None)
@given(
    error=arrays(np.float64, st.integers(12, 60), elements=st.floats(-5, 5)),
    window=st.integers(1, 10),
)
def test_accumulated_mean_error_is_eq8(error: np.ndarray, window: int) -> None:
    assert np.allclose(accumulated_mean_error(error, window), _eq8_loop(error, window))


def test_accumulated_mean_error_ignores_a_constant_offset_and_sees_a_step() -> None:
    assert np.all(accumulated_mean_error(np.full(300, 7.0), 100) == 0.0)
    step = np.r_[np.zeros(150), np.ones(150)]
    ame = accumulated_mean_error(step, 100)
    assert ame.shape == (200,)
    # The window starting on the last 0 sees 100 ones after it; one starting on a 1 sees none.
    assert ame.max() == pytest.approx(1.0) and ame[149] == pytest.approx(1.0)
    assert ame[0] == 0.0 and ame[150] == 0.0
    assert ame[50] == pytest.approx(0.01)


def test_yaw_error_wraps_and_stats() -> None:
    true = np.radians(np.array([179.0, -179.0, 0.0, 10.0]))
    est = np.radians(np.array([-179.0, 179.0, 1.0, 10.0]))
    assert np.allclose(np.degrees(yaw_error_rad(est, true)), [2.0, -2.0, 1.0, 0.0])
    stats = yaw_error_stats(est, true, ame_window=2)
    assert stats.frames == 4 and stats.final_deg == pytest.approx(0.0)
    assert stats.max_abs_deg == pytest.approx(2.0)
    assert stats.rms_deg == pytest.approx(math.sqrt((4 + 4 + 1) / 4))
    assert math.isnan(yaw_error_stats(est, true).max_ame_deg)  # too short for N = 100


def test_metrics_reject_bad_input() -> None:
    with pytest.raises(InputError):
        yaw_error_rad([0.0, 1.0], [0.0])
    with pytest.raises(InputError):
        yaw_error_rad([np.nan], [0.0])
    with pytest.raises(InputError):
        accumulated_mean_error(np.zeros(10), 10)
    with pytest.raises(InputError):
        accumulated_mean_error(np.zeros((3, 3)), 1)


# ---- trajectory metrics, cross-checked against evo ---------------------------------------------------


def _walk(seed: int, n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """A reference path (random 3-D walk, steps ~5 cm) and an estimate drifting from it."""
    rng = np.random.default_rng(seed)
    ref = np.cumsum(rng.normal(0.0, 0.03, (n, 3)) + np.array([0.03, 0.01, 0.0]), axis=0)
    est = ref + np.cumsum(rng.normal(0.0, 0.002, (n, 3)), axis=0)
    return est, ref


def _evo_trajectory(positions: np.ndarray):  # type: ignore[no-untyped-def]
    from evo.core.trajectory import PoseTrajectory3D

    quats = np.tile([1.0, 0.0, 0.0, 0.0], (len(positions), 1))
    return PoseTrajectory3D(positions, quats, np.arange(len(positions), dtype=np.float64))


def _evo_rpe_1m(evo_metrics: Any, ref: np.ndarray, est: np.ndarray) -> Any:
    """evo's translational RPE over 1 m of the reference path, computed for ``est``."""
    rpe = evo_metrics.RPE(
        evo_metrics.PoseRelation.translation_part,
        delta=1.0,
        delta_unit=evo_metrics.Unit.meters,
        pairs_from_reference=True,
    )
    rpe.process_data((_evo_trajectory(ref), _evo_trajectory(est)))
    return rpe


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ate_and_rpe_match_evo(seed: int) -> None:
    evo_metrics = pytest.importorskip("evo.core.metrics", reason="evo (dev extra) is not installed")
    from common.metrics import ate_rmse_m, rpe_translation

    est, ref = _walk(seed)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((_evo_trajectory(ref), _evo_trajectory(est)))
    assert ate_rmse_m(est, ref) == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)
    rpe = _evo_rpe_1m(evo_metrics, ref, est)
    ours = rpe_translation(est, ref, delta_m=1.0)
    assert ours.pairs == len(rpe.error)
    assert ours.mean_m == pytest.approx(rpe.get_statistic(evo_metrics.StatisticsType.mean), rel=1e-9)
    assert ours.rmse_m == pytest.approx(rpe.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-9)
    assert ours.mean_pct == pytest.approx(100.0 * ours.mean_m)


def test_horizontal_rpe_with_3d_pairs_matches_evo_with_true_altitude() -> None:
    """Error on x, y only with the pairs on the 3-D path = evo on 3-D with the estimate's z made true."""
    evo_metrics = pytest.importorskip("evo.core.metrics", reason="evo (dev extra) is not installed")
    from common.metrics import rpe_translation

    est, ref = _walk(5)
    est_true_z = np.c_[est[:, :2], ref[:, 2]]
    rpe = _evo_rpe_1m(evo_metrics, ref, est_true_z)
    ours = rpe_translation(est[:, :2], ref[:, :2], 1.0, reference_path_m=ref)
    assert ours.mean_m == pytest.approx(rpe.get_statistic(evo_metrics.StatisticsType.mean), rel=1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), offset=arrays(np.float64, 3, elements=st.floats(-100, 100)))
def test_rpe_ignores_a_constant_offset_and_ate_measures_it(seed: int, offset: np.ndarray) -> None:
    from common.metrics import ate_rmse_m, rpe_translation

    _, ref = _walk(seed, 120)
    assert rpe_translation(ref + offset, ref).mean_m == pytest.approx(0.0, abs=1e-9)
    assert ate_rmse_m(ref + offset, ref) == pytest.approx(float(np.linalg.norm(offset)), abs=1e-9)


def test_trajectory_metrics_refuse_bad_input() -> None:
    from common.metrics import ate_rmse_m, rpe_translation

    ref = np.zeros((5, 3))
    with pytest.raises(InputError):
        ate_rmse_m(np.zeros((4, 3)), ref)
    with pytest.raises(InputError):
        ate_rmse_m(np.full((5, 3), math.nan), ref)
    with pytest.raises(InputError):
        rpe_translation(ref, ref, delta_m=0.0)
    assert rpe_translation(ref, ref).pairs == 0  # never travels 1 m: no pairs, nan mean


def _random_walk_xy(seed: int, n: int = 300) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, 0.05, (n, 2)), axis=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), noise=st.floats(1e-4, 0.05))
def test_along_cross_split_adds_up_to_the_rpe(seed: int, noise: float) -> None:
    """``along^2 + cross^2`` is each pair's squared error: their mean squares add up to the RPE's."""
    from common.metrics import rpe_along_cross, rpe_translation

    ref = _random_walk_xy(seed)
    est = ref + np.random.default_rng(seed + 1).normal(0.0, noise, ref.shape)
    split = rpe_along_cross(est, ref, delta_m=1.0)
    rpe = rpe_translation(est, ref, delta_m=1.0)
    assert split.pairs == rpe.pairs > 0
    assert split.along_rmse_m**2 + split.cross_rmse_m**2 == pytest.approx(rpe.rmse_m**2, rel=1e-9)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(-0.05, 0.05), angle=st.floats(-0.05, 0.05))
def test_along_is_scale_and_cross_is_heading(seed: int, scale: float, angle: float) -> None:
    """A scaled path errs along each displacement only; a path rotated counter-clockwise errs to the left
    by ``sin(angle)`` and along by ``cos(angle) - 1`` per metre of displacement."""
    from common.metrics import path_pairs_by_distance, rpe_along_cross

    ref = _random_walk_xy(seed)
    pairs = np.array(path_pairs_by_distance(ref, 1.0))
    scaled = rpe_along_cross(ref * (1.0 + scale), ref, delta_m=1.0)
    assert scaled.cross_rmse_m == pytest.approx(0.0, abs=1e-12)
    mean_seg = float(np.mean(np.linalg.norm(ref[pairs[:, 1]] - ref[pairs[:, 0]], axis=1)))
    assert scaled.along_mean_m == pytest.approx(scale * mean_seg, rel=1e-9, abs=1e-15)
    c, s = math.cos(angle), math.sin(angle)
    rotated = rpe_along_cross(ref @ np.array([[c, s], [-s, c]]), ref, delta_m=1.0)
    seg = np.linalg.norm(ref[pairs[:, 1]] - ref[pairs[:, 0]], axis=1)
    assert rotated.cross_mean_m == pytest.approx(s * float(np.mean(seg)), rel=1e-9, abs=1e-12)
    assert rotated.along_mean_m == pytest.approx((c - 1.0) * float(np.mean(seg)), rel=1e-6, abs=1e-12)


def test_along_cross_without_pairs_or_motion_is_nan_and_refuses_bad_input() -> None:
    from common.metrics import rpe_along_cross, rpe_translation

    still = np.zeros((10, 2))
    split = rpe_along_cross(still, still, delta_m=1.0)
    assert split.pairs == 0 and math.isnan(split.cross_rmse_m)
    climb = np.zeros((10, 3))
    climb[:, 2] = np.linspace(0.0, 5.0, 10)  # pairs 1 m apart, none of them with a horizontal displacement
    assert rpe_translation(climb, climb).pairs > 0
    vertical = rpe_along_cross(climb, climb, delta_m=1.0)
    assert vertical.pairs == 0 and math.isnan(vertical.along_rmse_m)
    with pytest.raises(InputError):
        rpe_along_cross(np.zeros((5, 2)), np.zeros((6, 2)))
    with pytest.raises(InputError):
        rpe_along_cross(np.full((5, 2), np.nan), np.zeros((5, 2)))
