"""The variance of a measured yaw pair (:func:`common.yaw.honest.measured_variance_rad2`): its model, and
that it is honest on field flights the model was not fitted on (seed 13; fitted on seeds 0-9)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.consistency import error_consistency
from common.geometry import wrap_angle_rad
from common.sim.field import field_flight, field_trajectory, fisheye_camera
from common.sim.sensors import ImuNoise, simulate_imu
from common.yaw import (
    Provenance,
    YawSettings,
    YawTracker,
    gyro_delta_yaw_rad,
    honest,
    make_patch_grid,
    stages,
)
from common.yaw.fit import shift_of_homography_px
from common.yaw.held import HeldRate
from common.yaw.honest import (
    WARPED_FLOOR_DEG,
    held_coefficients,
    held_variance_terms,
    make_prior,
    measured_variance_rad2,
)
from common.yaw.stages import EstimateMethod, lens_of

#: a pair's inliers and the patches measured beside them that did not agree
_AGREEMENT = {"inliers": st.integers(1, 400), "failed": st.integers(0, 400)}


@settings(max_examples=50, deadline=None)
@given(residual=st.floats(0.0, 5.0), lever=st.floats(20.0, 2000.0), **_AGREEMENT)
def test_variance_grows_with_the_residual_and_the_warp_adds_its_floor(
    residual: float, inliers: int, failed: int, lever: float
) -> None:
    patches = inliers + failed
    raw = measured_variance_rad2(residual, inliers, patches, lever)
    warped = measured_variance_rad2(residual, inliers, patches, lever, warped=True)
    assert warped == pytest.approx(raw + math.radians(WARPED_FLOOR_DEG) ** 2 * patches / inliers**2)
    assert measured_variance_rad2(residual + 0.5, inliers, patches, lever) > raw > 0.0
    assert math.isfinite(measured_variance_rad2(math.inf, inliers, patches, lever))


@settings(max_examples=50, deadline=None)
@given(residual=st.floats(0.0, 5.0), shift=st.floats(0.0, 50.0), warped=st.booleans(), **_AGREEMENT)
def test_a_pair_is_averaged_over_its_inliers_and_scaled_by_the_patches_that_failed(
    residual: float, shift: float, inliers: int, failed: int, warped: bool
) -> None:
    """Every term is per patch: averaged over the inliers, times the measured patches over the inliers. Of
    the same patches, fewer agreeing is less certain; a patch that did not agree costs; a patch count below
    the inliers' (a caller's slip) counts as the inliers'."""
    patches = inliers + failed

    def variance(agreed: int, measured: int) -> float:
        return measured_variance_rad2(residual, agreed, measured, 100.0, warped, shift, 150.0)

    per_patch = variance(1, 1)
    assert variance(inliers, patches) == pytest.approx(per_patch * patches / inliers**2)
    assert variance(inliers, patches + 1) > variance(inliers, patches)
    if inliers > 1:
        assert variance(inliers - 1, patches) > variance(inliers, patches)
    assert variance(inliers, 0) == variance(inliers, inliers)


@settings(max_examples=50, deadline=None)
@given(ratio=st.floats(1.0, 1e6), **_AGREEMENT)
def test_a_pair_whose_correlations_are_ambiguous_is_less_certain(
    ratio: float, inliers: int, failed: int
) -> None:
    """The patches' median first-to-second peak ratio adds ``(AMBIGUITY_DEG / ratio)^2`` per patch: the lower
    the ratio (a periodic floor, blur), the larger; an unambiguous correlation (inf) adds nothing, and a ratio
    below 1 or NaN counts as 1."""
    patches = inliers + failed

    def variance(peak_ratio: float) -> float:
        return measured_variance_rad2(0.3, inliers, patches, 100.0, True, 2.0, 150.0, peak_ratio)

    added = (math.radians(honest.AMBIGUITY_DEG) / ratio) ** 2 * patches / inliers**2
    assert variance(ratio) == pytest.approx(variance(math.inf) + added)
    assert variance(ratio / 2.0 if ratio >= 2.0 else 1.0) >= variance(ratio)
    assert variance(math.nan) == variance(0.5) == variance(1.0) > variance(math.inf)


@settings(max_examples=50, deadline=None)
@given(turn_deg=st.floats(-5.0, 5.0), **_AGREEMENT)
def test_a_pair_measured_on_the_raw_frames_adds_the_windows_pull_once(
    turn_deg: float, inliers: int, failed: int
) -> None:
    """The window pulls every patch's shift towards zero alike, so an unrefined turn adds
    ``(UNREFINED_PULL * turn)^2`` once for the pair, however many patches agreed; either sign; NaN adds
    nothing."""
    patches = inliers + failed
    turn = math.radians(turn_deg)

    def variance(agreed: int, unrefined_turn_rad: float) -> float:
        return measured_variance_rad2(0.3, agreed, patches, 100.0, False, 2.0, 150.0, 8.0, unrefined_turn_rad)

    added = (honest.UNREFINED_PULL * turn) ** 2
    assert variance(inliers, turn) == pytest.approx(variance(inliers, 0.0) + added)
    assert variance(inliers, -turn) == variance(inliers, turn)
    assert variance(inliers, turn) - variance(inliers, 0.0) == pytest.approx(
        variance(patches, turn) - variance(patches, 0.0), abs=1e-15
    )
    assert variance(inliers, math.nan) == variance(inliers, 0.0)


def _measured_pairs(name: str, seed: int, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Errors and published variances of the measured pairs of a field flight (camera on the down mount),
    the gyro prior on."""
    error, variance, _ = _scored_pairs(name, seed, n_frames)
    return error, variance


def _scored_pairs(
    name: str, seed: int, n_frames: int, camera: CameraModel | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_measured_pairs` through ``camera`` (None: the scenario's lens), and which of the pairs were
    measured on the raw frames (not refined)."""
    flight = field_flight(name, seed=seed, n_frames=n_frames, camera=camera)
    settings = YawSettings(camera=flight.camera)
    frames = list(flight.frames())
    tracker = YawTracker(settings, make_patch_grid(frames[0].shape, settings))
    stamps, imu = flight.frame_stamps_s, flight.imu
    state = tracker.initial_state(frames[0], stamp_s=float(stamps[0]))
    estimates = []
    for k in range(1, len(frames)):
        gyro = gyro_delta_yaw_rad(imu.stamps_s, imu.gyro_rad_s, float(stamps[k - 1]), float(stamps[k]))
        state, estimate = tracker.track(state, frames[k], float(stamps[k]), gyro)
        estimates.append(estimate)
    error = wrap_angle_rad(np.array([e.delta_yaw_rad for e in estimates]) - np.diff(flight.yaw_rad))
    variance = np.array([e.delta_variance_rad2 for e in estimates])
    measured = np.array([e.provenance is Provenance.MEASURED for e in estimates])
    unrefined = np.array([e.method is EstimateMethod.PATCHES for e in estimates])
    return error[measured], variance[measured], unrefined[measured]


@pytest.mark.slow
def test_unrefined_pairs_through_a_fisheye_are_honest_regression(monkeypatch: pytest.MonkeyPatch) -> None:
    """Regression: a pair that turns less than ``refine_min_deg`` is measured on the raw frames only, and the
    window's pull reads its turn short by a share the residual does not see: 12-13 % through a 120 deg
    equidistant fisheye (2-6 % through the suite's lens). Without :data:`honest.UNREFINED_PULL` such pairs
    were published at a mean NEES of 5.6-9.9 on seed 13 (not used to choose it) of the checkerboard and
    field flights through that fisheye, 150 frames; with it they read 1.55 and 2.1, and every measured pair
    0.92 and 0.95 within 2 sigma (0.86 and 0.89 without)."""
    camera = fisheye_camera(320, 240, 120.0)

    def scored() -> tuple[float, float, int]:
        pairs = [_scored_pairs(name, 13, 150, camera) for name in ("checkerboard", "field")]
        error, variance, unrefined = (np.concatenate([p[i] for p in pairs]) for i in range(3))
        raw = error_consistency(error[unrefined], variance[unrefined])
        return raw.nees_mean, error_consistency(error, variance).within_2_sigma, int(unrefined.sum())

    nees, within, unrefined = scored()
    assert unrefined >= 60, unrefined
    assert nees < 2.5 and within >= 0.9, (nees, within)
    monkeypatch.setattr(honest, "UNREFINED_PULL", 0.0)
    before_nees, before_within, _ = scored()
    assert before_nees > 5.0 and before_within < within, (before_nees, before_within)


def _per_inlier_model(
    residual_share: float, floor_deg: float, shift_share: float, over_focal: bool
) -> Callable[..., float]:
    """The measured pair's variance as it was before every term was per patch: only the residual's term
    averaged over the inliers, the floor and the shift's term not (``over_focal`` False: the shift over the
    lever arm), with the constants of that time."""

    def variance(*args: Any) -> float:
        """``measured_variance_rad2``'s arguments, all given (as the central stage gives them); the patches
        and the peak ratio are not used."""
        residual_px, inliers, _, lever_px, warped, shift_px, focal_px = args[:7]
        residual = max(residual_px if math.isfinite(residual_px) else 1.0, honest.MIN_RESIDUAL_PX)
        lever = max(lever_px, 1.0)
        focal = focal_px if over_focal and focal_px is not None and math.isfinite(focal_px) else lever
        fit = residual_share * (residual / lever) ** 2 * 2.0 / max(inliers, 1)
        floor = math.radians(floor_deg) ** 2 if warped else 0.0
        return fit + floor + (shift_share * (shift_px if math.isfinite(shift_px) else 0.0) / focal) ** 2

    return variance


@pytest.mark.slow
def test_measured_pairs_are_honest_on_held_out_field_flights_regression(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Regression (issue 26): the measured pairs of the field suite had a mean NEES of 1.75 (0.885 within 2
    sigma) under the residual-and-floor model: the residual does not see the rotation a translation of the
    view turns into. With the image shift's term, on seed 13 (not fitted) of a calm flight and the combined
    field flight, the pooled pairs' mean NEES is near 1; the old model on the same pairs is overconfident."""
    pairs = [_measured_pairs(name, 13, 100) for name in ("checkerboard", "field")]
    error, variance = np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])
    assert error.size >= 150
    c = error_consistency(error, variance)
    assert 0.7 <= c.nees_mean <= 1.4, c
    assert 0.88 <= c.within_2_sigma <= 0.99, c
    monkeypatch.setattr(stages, "measured_variance_rad2", _per_inlier_model(0.24, 0.0205, 0.0, False))
    old_error, old_variance = _measured_pairs("field", 13, 100)
    old = error_consistency(old_error, old_variance)
    assert old.nees_mean > 1.5 and old.within_2_sigma < c.within_2_sigma, (old, c)


@settings(max_examples=50, deadline=None)
@given(shift=st.floats(0.0, 50.0), lever=st.floats(20.0, 2000.0), focal=st.floats(20.0, 4000.0))
def test_variance_grows_with_the_angle_the_view_moved(shift: float, lever: float, focal: float) -> None:
    """The shift's term is the angle the view moved, ``shift / focal``; without intrinsics the lever arm
    stands in for the focal length."""
    still = measured_variance_rad2(0.3, 1, 1, lever, focal_px=focal)
    moved = measured_variance_rad2(0.3, 1, 1, lever, shift_px=shift, focal_px=focal)
    assert moved == pytest.approx(still + (honest.SHIFT_SHARE * shift / focal) ** 2)
    assert measured_variance_rad2(0.3, 1, 1, lever, shift_px=shift + 1.0, focal_px=focal) > moved
    assert measured_variance_rad2(0.3, 1, 1, lever, shift_px=math.nan, focal_px=focal) == still
    assert measured_variance_rad2(0.3, 1, 1, lever) == still  # the focal length does not enter the fit's term
    no_lens = measured_variance_rad2(0.3, 1, 1, lever, shift_px=shift)
    assert no_lens == pytest.approx(still + (honest.SHIFT_SHARE * shift / lever) ** 2)
    assert measured_variance_rad2(0.3, 1, 1, lever, shift_px=shift, focal_px=math.nan) == no_lens


def test_the_lens_focal_length_is_the_scaled_cameras() -> None:
    """The central stage's lens gives the variance the focal length of the frames' own size (a calibration
    of another resolution is scaled), and none without intrinsics."""
    camera = CameraModel.from_hfov(640, 480, 90.0)
    settings = YawSettings(camera=camera)
    grid = make_patch_grid((240, 320), settings)
    assert lens_of(grid, settings).focal_px == pytest.approx(camera.fx / 2.0)
    assert lens_of(grid, YawSettings()).focal_px is None


@pytest.mark.slow
def test_wide_and_narrow_lenses_are_alike_honest_regression(monkeypatch: pytest.MonkeyPatch) -> None:
    """Regression (issue 26): the shift's term was ``shift / lever``, so a wide lens (120 deg, lever 1.24
    focal lengths) was published overconfident and a narrow one (90 deg, lever 0.64 focal lengths)
    cautious: on held-out seeds 10-19 (600 frames) the combined field flight's mean NEES was 1.66 and the
    low altitude's 0.61. As the angle the view moved (``shift / focal``) they read 1.20 and 0.72. On seed
    13 (not fitted; 100 frames) the two flights' mean NEES are now within a factor of 1.6 of each other;
    with the old term and constants they were more than 2.2 apart."""

    def ratio() -> float:
        wide, narrow = (_measured_pairs(name, 13, 100) for name in ("field", "low_altitude"))
        return error_consistency(*wide).nees_mean / error_consistency(*narrow).nees_mean

    now = ratio()
    assert 1 / 1.6 < now < 1.6, now
    monkeypatch.setattr(stages, "measured_variance_rad2", _per_inlier_model(0.1357, 0.01804, 0.01702, False))
    before = ratio()
    assert before > 2.2, before


@pytest.mark.slow
def test_pairs_that_few_patches_agreed_on_are_honest_regression(monkeypatch: pytest.MonkeyPatch) -> None:
    """Regression (issue 26): only the residual's term was averaged over the inliers, so a pair that few of
    its patches agreed on was published overconfident (held out, seeds 10-19, 600 frames: mean NEES 4.98
    below 20 inliers of 40, 1.57 at 20-29, 0.88 at 36-40; now 0.90, 0.94, 1.13). On seed 13's whole field
    flight (not fitted) the pairs below the median inlier count now read a mean NEES of 0.91; the previous
    model, given the same pairs' terms, published them at 1.39."""
    calls: dict[float, tuple[float, int, int, float, bool, float, float | None]] = {}

    def recorded(*args: float) -> float:
        variance = measured_variance_rad2(*args)  # type: ignore[arg-type]
        calls[variance] = args  # type: ignore[assignment]
        return variance

    monkeypatch.setattr(stages, "measured_variance_rad2", recorded)
    error, variance = _measured_pairs("field", 13, 600)
    terms = [calls[v] for v in variance]
    inliers = np.array([t[1] for t in terms])
    few = inliers < np.median(inliers)
    assert few.sum() >= 100
    previous = np.array([_per_inlier_model(0.1959, 0.01974, 0.01731, True)(*t) for t in terms])
    now_few = error_consistency(error[few], variance[few]).nees_mean
    before_few = error_consistency(error[few], previous[few]).nees_mean
    assert now_few < 1.15 < 1.3 < before_few, (now_few, before_few)


def test_bridged_pairs_are_honest_against_the_simulated_gyro() -> None:
    """Regression (issue 26): the bridge's variance was (0.5 deg/s * dt)^2 for the simulated MEMS gyro's
    0.3 deg/s bias (mean NEES about 0.36, every error within 2 sigma); now the gyro's bias and noise density
    over the gap, on 100 flights' gyros (own bias each) and stamp gaps of 25-200 ms."""
    stamps = np.arange(0.0, 8.0, 1.0 / 400.0)
    settings = YawSettings()
    errors, variances = [], []
    for seed in range(100):
        trajectory = field_trajectory(seed, duration_s=8.0)
        imu = simulate_imu(trajectory, stamps, ImuNoise(), seed)
        rng = np.random.default_rng(seed)
        t = 0.5
        while t < 7.5:
            gap = float(rng.uniform(0.025, 0.2))
            delta = gyro_delta_yaw_rad(imu.stamps_s, imu.gyro_rad_s, t, t + gap)
            assert delta is not None
            true = trajectory.sample(np.array([t, t + gap])).euler_rad[:, 2]
            errors.append(float(wrap_angle_rad(delta - (true[1] - true[0]))))
            variances.append(make_prior(settings, gap, delta, None, 0.0).variance_rad2)
            t += gap
    c = error_consistency(np.array(errors), np.array(variances))
    assert 0.90 <= c.within_2_sigma <= 0.98, c
    assert 0.75 <= c.nees_mean <= 1.3, c  # 100 bias draws: the mean's spread is about sqrt(2 / 100)


@settings(max_examples=50, deadline=None)
@given(
    angle=st.floats(-3.0, 3.0),
    tx=st.floats(-50.0, 50.0),
    ty=st.floats(-50.0, 50.0),
    cx=st.floats(0.0, 800.0),
    cy=st.floats(0.0, 600.0),
)
def test_the_shift_at_the_centre_is_the_translation_of_a_turn_about_it(
    angle: float, tx: float, ty: float, cx: float, cy: float
) -> None:
    """``shift_of_homography_px`` (the variance's shift term): a turn about the centre moves it by the
    translation that follows the turn, whatever the angle."""
    c, s = math.cos(angle), math.sin(angle)
    to_centre = np.array([[1.0, 0.0, cx], [0.0, 1.0, cy], [0.0, 0.0, 1.0]])
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    move = np.array([[1.0, 0.0, tx], [0.0, 1.0, ty], [0.0, 0.0, 1.0]])
    homography = move @ to_centre @ turn @ np.linalg.inv(to_centre)
    assert shift_of_homography_px(homography, (cx, cy)) == pytest.approx(math.hypot(tx, ty), abs=1e-6)
    assert shift_of_homography_px(np.zeros((3, 3)), (cx, cy)) == math.inf


@settings(max_examples=60, deadline=None)
@given(
    spread=st.floats(0.0, 2.0),
    lag=st.floats(0.0, 0.3),
    dt=st.floats(0.005, 0.2),
    since=st.floats(0.0, 1.0),
    more=st.floats(0.001, 0.5),
)
def test_a_held_pairs_variance_grows_with_the_time_since_measured_and_the_rates_scatter(
    spread: float, lag: float, dt: float, since: float, more: float
) -> None:
    """The terms times the coefficients, never 0, growing with the time since the rate applied and with the
    window's scatter; the gate's tolerance does not set it."""
    settings_ = YawSettings()
    held = HeldRate(0.3, lag, spread, 4)
    prior = make_prior(settings_, dt, None, held, since)
    expected = float(held_variance_terms(held, dt, since) @ held_coefficients())
    assert prior.variance_rad2 == pytest.approx(expected) and prior.variance_rad2 > 0.0
    assert make_prior(settings_, dt, None, held, since + more).variance_rad2 > prior.variance_rad2
    wider = HeldRate(0.3, lag, spread + 0.1, 4)
    assert make_prior(settings_, dt, None, wider, since).variance_rad2 > prior.variance_rad2
