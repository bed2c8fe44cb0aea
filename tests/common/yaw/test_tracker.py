from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.sim.flight import hover_flight
from common.yaw import (
    EstimateMethod,
    Provenance,
    YawSettings,
    YawTracker,
    estimate_pair,
    for_frame,
    make_patch_grid,
    measure_patches,
    merge_measurements,
    patch_spectra_from_crops,
)

from .conftest import PairMaker


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    delta_yaw_deg=st.floats(-10.0, 10.0),
    shift_x_px=st.floats(-20.0, 20.0),
    shift_y_px=st.floats(-20.0, 20.0),
    yaw0_deg=st.floats(-180.0, 180.0),
)
def test_single_pair_rotation_within_005_deg(
    nadir_pair: PairMaker, delta_yaw_deg: float, shift_x_px: float, shift_y_px: float, yaw0_deg: float
) -> None:
    a, b = nadir_pair(delta_yaw_deg, (shift_x_px, shift_y_px), yaw0_deg)
    estimate = estimate_pair(a, b, YawSettings())
    assert not estimate.low_confidence
    assert abs(math.degrees(estimate.delta_yaw_rad) - delta_yaw_deg) < 0.05


@pytest.mark.parametrize("delta_yaw_deg", [30.0, -75.0, 120.0, 179.0])
def test_tracker_survives_a_spin_by_global_prealignment(nadir_pair: PairMaker, delta_yaw_deg: float) -> None:
    """A fast spin or dropped frames: far beyond what per-patch shifts can follow."""
    a, b = nadir_pair(delta_yaw_deg, (6.0, -4.0))
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    state, estimate = tracker.track(tracker.initial_state(a), b)
    assert estimate.method is EstimateMethod.GLOBAL_PREALIGNED
    assert not estimate.low_confidence
    assert abs(math.degrees(estimate.delta_yaw_rad) - delta_yaw_deg) < 0.05
    assert state.yaw_rad == estimate.yaw_rad == estimate.delta_yaw_rad


def test_global_prealignment_handles_zoom(nadir_pair: PairMaker) -> None:
    a, b = nadir_pair(-14.0, (3.0, 5.0), altitude_ratio=1.0 / 0.885)
    estimate = estimate_pair(a, b, YawSettings())
    assert estimate.method is EstimateMethod.GLOBAL_PREALIGNED
    assert abs(math.degrees(estimate.delta_yaw_rad) + 14.0) < 0.05


@pytest.fixture(scope="module")
def hover_frames() -> tuple[list[np.ndarray], np.ndarray]:
    flight = hover_flight(seed=0, n_frames=160)
    return list(flight.frames()), flight.yaw_rad


def test_hover_yaw_follows_the_simulator_truth(hover_frames: tuple[list[np.ndarray], np.ndarray]) -> None:
    """Sign and size of the vehicle's yaw from the downward camera, against the simulator's truth."""
    frames, true_yaw = hover_frames
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    state = tracker.initial_state(frames[0])
    estimated = [0.0]
    deltas = []
    for frame in frames[1:]:
        state, estimate = tracker.track(state, frame)
        assert estimate.method in (EstimateMethod.PATCHES, EstimateMethod.REFINED)
        assert estimate.provenance is Provenance.MEASURED and not estimate.low_confidence
        estimated.append(estimate.yaw_rad)
        deltas.append(estimate.delta_yaw_rad)
    true_delta = np.diff(true_yaw)
    assert np.degrees(np.ptp(true_yaw)) > 5.0  # the excerpt does turn
    error_deg = np.degrees(np.asarray(estimated) - (true_yaw - true_yaw[0]))
    assert np.max(np.abs(error_deg)) < 0.3
    assert np.max(np.abs(np.degrees(np.asarray(deltas) - true_delta))) < 0.1


def test_cluster_split_equals_in_process_tracking(hover_frames: tuple[list[np.ndarray], np.ndarray]) -> None:
    """Workers on index subsets (crops only, sticky previous spectra) + conclude == track, to 1e-9 deg."""
    frames = hover_frames[0][:25]
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    tracker = YawTracker(settings, grid)
    shares = [np.arange(0, 13), np.arange(13, 27), np.arange(27, grid.n_patches)]

    def worker_spectra(frame: np.ndarray) -> list:
        return [patch_spectra_from_crops(grid.crop(frame, idx), idx, settings) for idx in shares]

    in_process = tracker.initial_state(frames[0])
    master = tracker.initial_state(frames[0], with_spectra=False)
    previous = worker_spectra(frames[0])
    for frame in frames[1:]:
        in_process, expected = tracker.track(in_process, frame)
        current = worker_spectra(frame)
        parts = [measure_patches(p, c, settings) for p, c in zip(previous, current, strict=True)]
        previous = current
        master, estimate = tracker.conclude(master, frame, merge_measurements(parts[::-1]))
        assert abs(math.degrees(estimate.yaw_rad - expected.yaw_rad)) < 1e-9
        assert estimate.inlier_count == expected.inlier_count
    assert master.yaw_rad == in_process.yaw_rad


def test_conclude_with_a_missing_worker_still_estimates(
    hover_frames: tuple[list[np.ndarray], np.ndarray],
) -> None:
    frames, true_yaw = hover_frames
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    grid = make_patch_grid(frames[0].shape, settings)
    tracker = YawTracker(settings, grid)
    idx = np.arange(0, grid.n_patches, 2)  # half of the patches
    before = patch_spectra_from_crops(grid.crop(frames[40], idx), idx, settings)
    after = patch_spectra_from_crops(grid.crop(frames[41], idx), idx, settings)
    state = tracker.initial_state(frames[40], with_spectra=False)
    _, estimate = tracker.conclude(state, frames[41], measure_patches(before, after, settings))
    assert estimate.patch_count == idx.size
    assert abs(math.degrees(estimate.delta_yaw_rad - (true_yaw[41] - true_yaw[40]))) < 0.1


def test_garbage_frames_raise_clear_errors(nadir_pair: PairMaker) -> None:
    a, b = nadir_pair(1.0)
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    state = tracker.initial_state(a)
    cases: list[tuple[Any, str]] = [
        (np.zeros((0, 0), dtype=np.uint8), "empty"),
        (b.astype(np.float32), "uint8"),
        (np.stack([b, b, b], axis=-1), r"\(H, W\)"),
        (b[:, :700], "shape"),
    ]
    for bad, message in cases:
        with pytest.raises(InputError, match=message):
            tracker.track(state, bad)
    with pytest.raises(InputError, match="same shape"):
        estimate_pair(a, b[:400], settings)
    with pytest.raises(InputError, match="uint8"):
        estimate_pair(a.astype(np.int16), b, settings)


@pytest.mark.parametrize("level", [0, 255])
def test_black_or_saturated_frame_is_flagged_not_guessed(nadir_pair: PairMaker, level: int) -> None:
    a, b = nadir_pair(2.0)
    flat = np.full_like(b, level)
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    state = tracker.initial_state(a)
    state, estimate = tracker.track(state, flat)
    assert estimate.low_confidence and estimate.method is EstimateMethod.NONE
    assert estimate.delta_yaw_rad == 0.0 and state.yaw_rad == 0.0
    # and back from the flat frame to texture: nothing to compare with either
    state, estimate = tracker.track(state, b)
    assert estimate.low_confidence and estimate.delta_yaw_rad == 0.0
    assert estimate_pair(a, flat, settings).low_confidence


def test_unrelated_noise_frames_are_low_confidence() -> None:
    rng = np.random.default_rng(7)
    a = rng.integers(0, 256, (480, 752), dtype=np.uint8)
    b = rng.integers(0, 256, (480, 752), dtype=np.uint8)
    estimate = estimate_pair(a, b, YawSettings())
    assert estimate.low_confidence
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    tracker = YawTracker(settings, make_patch_grid(a.shape, settings))
    _, tracked = tracker.track(tracker.initial_state(a), b)
    assert tracked.low_confidence


def test_tracker_rejects_a_grid_of_other_settings() -> None:
    grid = make_patch_grid((480, 752), YawSettings(patch_size_px=48))
    with pytest.raises(InputError):
        YawTracker(YawSettings(), grid)


def test_dropped_frames_hover_stays_accurate_through_the_fallback() -> None:
    """Every 4th frame of the hover (up to ~8 deg and a tilt change between frames): pre-aligned patches."""
    flight = hover_flight(seed=0, n_frames=481)
    kept = list(range(0, 481, 4))
    frames = [flight.frame(i) for i in kept]
    true_yaw = flight.yaw_rad[kept]
    settings = YawSettings()
    settings = for_frame(settings, frames[0].shape)
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    state = tracker.initial_state(frames[0])
    methods = set()
    for k, frame in enumerate(frames[1:], start=1):
        state, estimate = tracker.track(state, frame)
        methods.add(estimate.method)
        assert not estimate.low_confidence
        assert abs(math.degrees(estimate.delta_yaw_rad - (true_yaw[k] - true_yaw[k - 1]))) < 0.25
    # the held yaw rate turns frame k back (cheap) before any global stage is needed
    assert methods & {EstimateMethod.GLOBAL_PREALIGNED, EstimateMethod.PRIOR_PREALIGNED}
    assert abs(math.degrees(state.yaw_rad - (true_yaw[-1] - true_yaw[0]))) < 0.5


def test_master_alone_concludes_from_an_empty_measurement(nadir_pair: PairMaker) -> None:
    """No worker answered: the central stage still estimates from the two frames (flagged by its method)."""
    a, b = nadir_pair(3.0, (5.0, 2.0))
    settings = YawSettings()
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    tracker = YawTracker(settings, grid)
    empty = merge_measurements([])
    state, estimate = tracker.conclude(tracker.initial_state(a, with_spectra=False), b, empty)
    assert estimate.method is EstimateMethod.GLOBAL_PREALIGNED
    assert abs(math.degrees(estimate.delta_yaw_rad) - 3.0) < 0.05
    assert state.seq == 1 and state.previous_spectra is None
