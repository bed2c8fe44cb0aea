"""The variance of a measured yaw pair (:func:`common.yaw.honest.measured_variance_rad2`): its model, and
that it is honest on a field flight the model was not fitted on (seed 13; fitted on seeds 0-3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.consistency import error_consistency
from common.geometry import wrap_angle_rad
from common.sim.field import field_flight, field_trajectory
from common.sim.sensors import ImuNoise, simulate_imu
from common.yaw import Provenance, YawSettings, YawTracker, gyro_delta_yaw_rad, make_patch_grid
from common.yaw.honest import WARPED_FLOOR_DEG, make_prior, measured_variance_rad2


@settings(max_examples=50, deadline=None)
@given(
    residual=st.floats(0.0, 5.0),
    inliers=st.integers(1, 400),
    lever=st.floats(20.0, 2000.0),
)
def test_variance_grows_with_the_residual_and_the_warp_adds_its_floor(
    residual: float, inliers: int, lever: float
) -> None:
    raw = measured_variance_rad2(residual, inliers, lever)
    warped = measured_variance_rad2(residual, inliers, lever, warped=True)
    assert warped == pytest.approx(raw + math.radians(WARPED_FLOOR_DEG) ** 2)
    assert measured_variance_rad2(residual + 0.5, inliers, lever) > raw > 0.0
    assert measured_variance_rad2(residual, inliers + 1, lever) < raw
    assert math.isfinite(measured_variance_rad2(math.inf, inliers, lever))


@pytest.mark.slow
def test_measured_pairs_are_honest_on_a_held_out_field_flight() -> None:
    """Regression (issue 26): raw patch pairs reported about twice their error's standard deviation (mean
    NEES 0.24) and warped (refined) pairs too little (1.15); each kind now has a mean NEES near 1."""
    flight = field_flight("checkerboard", seed=13, n_frames=160)
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
    warped = variance > math.radians(WARPED_FLOOR_DEG) ** 2
    for kind in (measured & ~warped, measured & warped):
        assert np.count_nonzero(kind) >= 30
        c = error_consistency(error[kind], variance[kind])
        assert 0.6 <= c.nees_mean <= 1.6, c
        assert 0.88 <= c.within_2_sigma <= 0.995, c


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
