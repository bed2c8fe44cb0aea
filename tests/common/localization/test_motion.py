"""The tracker's constant-velocity Kalman filter (common.localization.motion) and the simulated gyro."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.localization.motion import (
    MotionSettings,
    MotionState,
    motion_predict,
    motion_rate_update,
    motion_start,
    motion_update,
)
from common.localization.pose import CameraPose, perturb, rotation_matrices
from common.sim.objects import frame_gyro, object_flight
from common.sim.sensors import ImuNoise

finite = st.floats(-2.0, 2.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)


def _state(p: np.ndarray, rotvec: np.ndarray, v: np.ndarray, w: np.ndarray) -> MotionState:
    pose = CameraPose(p, rotation_matrices(rotvec[None])[0])
    return replace(motion_start(pose, np.eye(6) * 1e-4, 0.5, 0.5), velocity_m_s=v, angular_rate_rad_s=w)


@settings(max_examples=40, deadline=None)
@given(vec3, vec3, vec3, vec3, st.floats(0.0, 0.2))
def test_prediction_moves_at_constant_velocity_and_grows_a_valid_covariance(
    p: np.ndarray, rotvec: np.ndarray, v: np.ndarray, w: np.ndarray, dt: float
) -> None:
    state = _state(p, rotvec, v, w)
    moved = motion_predict(state, dt, MotionSettings())
    assert np.allclose(moved.p_world_camera_m, p + v * dt)
    expected_R = perturb(state.R_world_camera[None], (w * dt)[None])[0]
    assert np.allclose(moved.R_world_camera, expected_R, atol=1e-12)  # (arccos is blunt near 0)
    assert np.allclose(moved.covariance, moved.covariance.T)
    assert np.linalg.eigvalsh(moved.covariance).min() > -1e-12
    assert np.trace(moved.covariance) >= np.trace(state.covariance) - 1e-12


@settings(max_examples=40, deadline=None)
@given(vec3, vec3, st.floats(1e-6, 1e-2))
def test_update_with_the_predicted_pose_keeps_it_and_shrinks_the_covariance(
    p: np.ndarray, rotvec: np.ndarray, sigma: float
) -> None:
    state = motion_predict(_state(p, rotvec, np.zeros(3), np.zeros(3)), 0.05, MotionSettings())
    result = motion_update(state, state.pose, np.eye(6) * sigma**2, MotionSettings())
    assert not result.rejected and result.nis < 1e-9
    assert np.allclose(result.state.p_world_camera_m, state.p_world_camera_m)
    assert np.trace(result.state.covariance) < np.trace(state.covariance)


def test_update_pulls_towards_the_measurement_by_the_variances() -> None:
    state = _state(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))  # position variance 1e-4
    measured = CameraPose(np.array([0.01, 0.0, 0.0]), state.R_world_camera)
    result = motion_update(state, measured, np.eye(6) * 1e-4, MotionSettings())
    assert np.allclose(result.state.p_world_camera_m, [0.005, 0.0, 0.0])  # equal variances: half way


def test_a_measurement_far_outside_the_gate_is_rejected_and_changes_nothing() -> None:
    state = _state(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    snapped = CameraPose(np.array([0.5, 0.0, 0.0]), state.R_world_camera)
    result = motion_update(state, snapped, np.eye(6) * 1e-4, MotionSettings())
    assert result.rejected and result.nis > MotionSettings().gate
    assert result.state is state


def test_rate_update_follows_a_precise_gyro_and_bad_rates_are_refused() -> None:
    state = _state(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    updated = motion_rate_update(state, np.array([0.0, 0.0, 0.3]), 1e-4)
    assert np.allclose(updated.angular_rate_rad_s, [0.0, 0.0, 0.3], atol=1e-6)
    with pytest.raises(InputError):
        motion_rate_update(state, np.array([0.0, np.nan, 0.0]), 1e-3)
    with pytest.raises(InputError):
        motion_rate_update(state, np.zeros(3), 0.0)
    with pytest.raises(InputError):
        motion_predict(state, -0.1, MotionSettings())
    with pytest.raises(InputError):
        MotionSettings(acceleration_m_s2=float("nan"))


def test_an_ideal_frame_gyro_integrates_to_the_flight_rotations() -> None:
    flight = object_flight(40, seed=3)
    gyro = frame_gyro(flight, ImuNoise.ideal(), seed=0)
    R = flight.R_world_camera[0]
    for k in range(1, flight.n_frames):
        dt = flight.times_s[k] - flight.times_s[k - 1]
        R = R @ rotation_matrices((gyro[k] * dt)[None])[0]  # camera-frame rate: right-multiplied
        assert np.allclose(R, flight.R_world_camera[k], atol=1e-9)
    noisy = frame_gyro(flight, ImuNoise(), seed=0)
    assert 0.0 < np.abs(noisy[1:] - gyro[1:]).max() < np.radians(3.0)
