"""Levelled correspondences (common.yaw.level): a tilted camera's translation is no turn, and the turn
measured is the heading's; the tilt from the IMU's specific force; the tracker's level views."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.ground import make_ground_texture, render_ground_view
from common.yaw import (
    YawSettings,
    YawTracker,
    fit_correspondences,
    make_patch_grid,
    rotation_of_homography_rad,
)
from common.yaw.level import R_level_body_of_up, levelling_homography, up_in_imu

CAMERA = CameraModel.from_hfov(320, 240, 90.0)


def _grid_px() -> np.ndarray:
    xs, ys = np.meshgrid(np.linspace(40.0, 280.0, 7), np.linspace(30.0, 210.0, 5))
    return np.column_stack([xs.ravel(), ys.ravel()])


def _floor_correspondences(
    R_world_body_a: np.ndarray, p_a_m: np.ndarray, R_world_body_b: np.ndarray, p_b_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Grid pixels of view a and where the floor (z = 0) they see lands in view b (down mount, pinhole)."""
    K, src = CAMERA.K, _grid_px()
    R_a, R_b = R_world_body_a @ R_BODY_CAMERA_DOWN, R_world_body_b @ R_BODY_CAMERA_DOWN
    rays = np.column_stack([src, np.ones(len(src))]) @ np.linalg.inv(K).T @ R_a.T
    floor = p_a_m + (-p_a_m[2] / rays[:, 2])[:, None] * rays
    seen = (floor - p_b_m) @ R_b
    dst = seen[:, :2] / seen[:, 2:3] @ K[:2, :2].T + K[:2, 2]
    return src, dst


def _mapped(H: np.ndarray, px: np.ndarray) -> np.ndarray:
    m = np.column_stack([px, np.ones(len(px))]) @ H.T
    return m[:, :2] / m[:, 2:3]


def _turn(src: np.ndarray, dst: np.ndarray) -> float:
    fit = fit_correspondences(src, dst, YawSettings())
    assert fit.ok
    return rotation_of_homography_rad(fit.homography, (CAMERA.cx, CAMERA.cy))


@settings(max_examples=60, deadline=None)
@given(
    tilt_a=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
    tilt_b=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
    yaw_a=st.floats(-math.pi, math.pi),
    turn=st.floats(-0.2, 0.2),
    move=st.tuples(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-0.05, 0.05)),
    height_m=st.floats(0.5, 3.0),
)
def test_in_level_views_the_floor_turns_by_the_heading_change(
    tilt_a: tuple[float, float],
    tilt_b: tuple[float, float],
    yaw_a: float,
    turn: float,
    move: tuple[float, float, float],
    height_m: float,
) -> None:
    """Exact correspondences of the floor between two tilted, moved and turned views, mapped into each
    view's level view: the fitted similarity's turn is the ZYX yaw's change, whatever the tilts."""
    R_a = matrix_from_euler(tilt_a[0], tilt_a[1], yaw_a)
    R_b = matrix_from_euler(tilt_b[0], tilt_b[1], yaw_a + turn)
    p_a = np.array([0.0, 0.0, height_m])
    src, dst = _floor_correspondences(R_a, p_a, R_b, p_a + np.array(move))
    before = levelling_homography(CAMERA.K, matrix_from_euler(*tilt_a, 0.0), R_BODY_CAMERA_DOWN)
    after = levelling_homography(CAMERA.K, matrix_from_euler(*tilt_b, 0.0), R_BODY_CAMERA_DOWN)
    assert _turn(_mapped(before, src), _mapped(after, dst)) == pytest.approx(turn, abs=1e-7)


def test_a_tilted_camera_reads_its_translation_as_a_turn_unless_levelled_regression() -> None:
    """The finding behind the level views: rolled 10 deg, 0.2 m across the floor at 1 m and no turn, the
    raw views' similarity turns by about tilt x move / height / 2."""
    R = matrix_from_euler(math.radians(10.0), 0.0, 0.3)
    p_a = np.array([0.0, 0.0, 1.0])
    src, dst = _floor_correspondences(
        R, p_a, R, p_a + np.array([0.2 * math.cos(0.3), 0.2 * math.sin(0.3), 0.0])
    )
    raw = _turn(src, dst)
    assert abs(raw) > math.radians(0.3)
    level = levelling_homography(
        CAMERA.K, matrix_from_euler(math.radians(10.0), 0.0, 0.0), R_BODY_CAMERA_DOWN
    )
    assert abs(_turn(_mapped(level, src), _mapped(level, dst))) < 1e-7


def test_a_level_body_levels_into_the_fixed_mount_view() -> None:
    assert np.allclose(levelling_homography(CAMERA.K, np.eye(3), R_BODY_CAMERA_DOWN), np.eye(3), atol=1e-12)


def _spinning_imu(roll: float, pitch: float, rate_rad_s: float, hz: float = 400.0, seconds: float = 4.0):
    """Noise-free IMU of a body at a constant tilt turning about the world's vertical."""
    t = np.arange(0.0, seconds, 1.0 / hz)
    R = matrix_from_euler(np.full(t.size, roll), np.full(t.size, pitch), rate_rad_s * t)  # (N, 3, 3)
    gyro = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, rate_rad_s]))  # R^T w_world
    accel = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, 9.81]))
    return t, gyro, accel


@pytest.mark.parametrize("rate_rad_s", [0.0, 1.5])
def test_the_up_direction_of_a_turning_tilted_body(rate_rad_s: float) -> None:
    """The window's specific force is turned into the body at the frame: a body turning at 1.5 rad/s (over
    4 rad in the 3 s window) at a 5 deg roll and -3 deg pitch still reads its tilt."""
    roll, pitch = math.radians(5.0), math.radians(-3.0)
    t, gyro, accel = _spinning_imu(roll, pitch, rate_rad_s)
    up = up_in_imu(t, gyro, accel, 3.9)
    assert up is not None
    R = R_level_body_of_up(up)
    error_rad = np.linalg.norm(R @ np.array([0.0, 0.0, 1.0]) - matrix_from_euler(roll, pitch, 0.0)[:, 2])
    assert error_rad < math.radians(0.05)


def test_the_up_direction_needs_half_a_window_and_finite_samples() -> None:
    t, gyro, accel = _spinning_imu(0.05, 0.0, 0.5)
    assert up_in_imu(t, gyro, accel, 1.0) is None  # 1 s of samples for a 3 s window
    assert up_in_imu(t, gyro, accel, 1.0, window_s=1.0) is not None
    bad = accel.copy()
    bad[300] = np.nan
    assert up_in_imu(t, gyro, bad, 3.0) is None
    assert up_in_imu(t, gyro, np.zeros_like(accel), 3.0) is None  # free fall: no up
    with pytest.raises(InputError):
        up_in_imu(t, gyro[:, :2], accel, 3.0)
    with pytest.raises(InputError):
        up_in_imu(t, gyro, accel, math.nan)
    with pytest.raises(InputError):
        R_level_body_of_up([0.0, 0.0, 0.0])


def test_the_tracker_measures_a_tilted_translation_as_no_turn_in_level_views() -> None:
    """Two rendered views, rolled 10 deg, 0.1 m apart across the floor at 1 m, the same heading: the raw
    fit reads a turn, the level views (each frame's tilt given) none."""
    texture = make_ground_texture(seed=3, size_px=1024, texel_m=0.004)
    R_world_body = matrix_from_euler(math.radians(10.0), 0.0, 0.0)
    R_world_camera = R_world_body @ R_BODY_CAMERA_DOWN
    a = render_ground_view(texture, CAMERA, R_world_camera, [0.0, 0.0, 1.0])
    b = render_ground_view(texture, CAMERA, R_world_camera, [0.1, 0.0, 1.0])
    yaw_settings = YawSettings(camera=CAMERA)
    tracker = YawTracker(yaw_settings, make_patch_grid(a.shape, yaw_settings))
    _, raw = tracker.track(tracker.initial_state(a), b)
    tilt = matrix_from_euler(math.radians(10.0), 0.0, 0.0)
    state, level = tracker.track(tracker.initial_state(a, R_level_body=tilt), b, R_level_body=tilt)
    assert abs(raw.delta_yaw_rad) > math.radians(0.2)
    assert abs(level.delta_yaw_rad) < math.radians(0.02)
    assert state.R_level_body is not None
    with pytest.raises(InputError):
        tracker.track(state, b, R_level_body=np.full((3, 3), np.nan))
