"""Camera poses: every convention converts both ways, rotations never pass through Euler angles."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import InputError
from common.geometry import R_BODY_CAMERA_FORWARD, matrix_from_euler
from common.localization.pose import (
    CameraPose,
    mean_rotation,
    parse_pose_numbers,
    perturb,
    pose_errors,
    rotation_angle_rad,
    rotation_matrices,
    rotation_vectors,
)
from common.localization.search import cloud_covariance

vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=60, deadline=None)
@given(vectors)
def test_exp_and_log_are_inverse_and_match_opencv(v: np.ndarray) -> None:
    R = rotation_matrices(v[None])[0]
    assert np.allclose(R, cv2.Rodrigues(v)[0], atol=1e-9)
    back = rotation_vectors(R[None])[0]
    assert np.allclose(rotation_matrices(back[None])[0], R, atol=1e-9)
    assert np.linalg.norm(back) <= np.pi + 1e-9


@settings(max_examples=40, deadline=None)
@given(vectors, vectors, st.integers(0, 2**31))
def test_pose_errors_take_position_and_angles_in_the_covariances_sense_regression(
    rvec: np.ndarray, p_m: np.ndarray, seed: int
) -> None:
    """Regression: the localizer's consistency lines took the position error as estimate minus truth and the
    angles as truth about the estimate, so the position-rotation correlations of the covariance (the fused
    one, or the cloud's: particle about centre) were measured against errors whose correlations had the
    other sign; the full covariance read as wrong and was shrunk to its diagonal. The errors of truths
    about an estimate now have the covariance the cloud of those truths about it has, cross terms too."""
    rng = np.random.default_rng(seed)
    R_est = rotation_matrices(rvec[None])[0]
    n = 64
    # correlated position and angle offsets: x with the rotation about y, as a locked-off pose's are
    mix = np.eye(6)
    mix[4, 0] = mix[0, 4] = 0.9
    offsets = rng.normal(size=(n, 6)) @ mix * np.array([0.02, 0.02, 0.02, 0.01, 0.01, 0.01])
    p_true = p_m + offsets[:, :3]
    R_true = perturb(np.repeat(R_est[None], n, axis=0), offsets[:, 3:])
    errors = pose_errors(p_true, R_true, np.repeat(p_m[None], n, axis=0), np.repeat(R_est[None], n, axis=0))
    assert np.allclose(errors, offsets, atol=1e-9)
    estimate = CameraPose(p_m, R_est)
    assert np.allclose(cloud_covariance(p_true, R_true, estimate), errors.T @ errors / n, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(vectors, vectors)
def test_camera_from_world_conventions_round_trip(rvec: np.ndarray, tvec: np.ndarray) -> None:
    pose = CameraPose.from_rvec_tvec(rvec, tvec)
    # OpenCV's meaning: X_camera = R(rvec) X_world + tvec
    X = np.array([0.3, -0.1, 2.0])
    assert np.allclose(pose.R_camera_world @ X + pose.t_camera_world_m, cv2.Rodrigues(rvec)[0] @ X + tvec)
    again = CameraPose.from_T_camera_world(pose.T_camera_world())
    assert np.allclose(again.p_world_camera_m, pose.p_world_camera_m)
    assert np.allclose(again.R_world_camera, pose.R_world_camera)
    r2, t2 = pose.rvec_tvec()
    assert np.allclose(rotation_matrices(r2[None])[0], cv2.Rodrigues(rvec)[0], atol=1e-9)
    assert np.allclose(t2, tvec)


def test_body_state_round_trip_and_no_gimbal_lock_inside() -> None:
    state = np.array([1.0, 2.0, 3.0, 0.2, -0.3, 1.1])
    pose = CameraPose.from_body_state(state, R_BODY_CAMERA_FORWARD)
    assert np.allclose(pose.body_state(R_BODY_CAMERA_FORWARD), state)
    # at pitch = 90 deg the Euler angles lock; the pose does not: small turns about every axis stay distinct
    locked = CameraPose.from_body_state([0, 0, 0, 0.0, np.pi / 2, 0.0], R_BODY_CAMERA_FORWARD)
    turns = np.radians(1.0) * np.eye(3)
    turned = perturb(np.repeat(locked.R_world_camera[None], 3, axis=0), turns)
    angles = rotation_angle_rad(turned[:, None], turned[None, :])
    assert np.all(angles[~np.eye(3, dtype=bool)] > np.radians(1.0))
    assert np.allclose(rotation_angle_rad(turned, locked.R_world_camera), np.radians(1.0))


def test_mean_rotation_is_the_rotation_for_identical_and_symmetric_sets() -> None:
    R = matrix_from_euler(0.3, 0.2, -1.0)
    assert np.allclose(mean_rotation(np.repeat(R[None], 4, axis=0), np.ones(4)), R)
    turns = np.radians(5.0) * np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    pair = perturb(np.repeat(R[None], 2, axis=0), turns)
    assert np.allclose(mean_rotation(pair, np.ones(2)), R, atol=1e-12)


def test_bad_poses_are_refused() -> None:
    with pytest.raises(InputError, match="6 numbers"):
        parse_pose_numbers([1.0, 2.0])
    with pytest.raises(InputError, match="last row"):
        parse_pose_numbers([1.0] * 16)
    with pytest.raises(InputError, match="finite"):
        parse_pose_numbers([np.nan, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="rotation matrix"):
        CameraPose(np.zeros(3), np.diag([1.0, 1.0, -1.0]))
