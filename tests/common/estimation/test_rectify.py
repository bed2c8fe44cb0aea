"""Orthogonal rectification (paper C III-C): the rotation and homography against the geometry of the
simulator, the paper's corner construction, and rendered views."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.rectify import (
    RectificationError,
    ground_corners,
    rectify_frame,
    rectifying_homography,
    rectifying_rotation,
)
from common.geometry import R_BODY_CAMERA_DOWN, matrix_from_euler
from common.sim.ground import GroundTexture, camera_pose_from_body, render_ground_view

CAMERA = CameraModel.default()
tilt = st.floats(-0.15, 0.15)


@given(tilt, tilt, st.floats(-math.pi, math.pi))
def test_rectifying_rotation_levels_the_camera_and_keeps_the_heading(
    roll: float, pitch: float, yaw: float
) -> None:
    R_world_cam = matrix_from_euler(roll, pitch, yaw) @ R_BODY_CAMERA_DOWN
    R_world_rcam = matrix_from_euler(0.0, 0.0, yaw) @ R_BODY_CAMERA_DOWN
    R_rcam_cam = rectifying_rotation(roll, pitch, R_BODY_CAMERA_DOWN)
    assert np.allclose(R_rcam_cam, R_world_rcam.T @ R_world_cam, atol=1e-12)
    # the rectified optical axis points straight down
    assert np.allclose(R_world_rcam[:, 2], [0.0, 0.0, -1.0])


@given(tilt, tilt, st.floats(-math.pi, math.pi), st.floats(1.0, 10.0))
def test_homography_equals_the_papers_corner_construction(
    roll: float, pitch: float, yaw: float, h: float
) -> None:
    """Corners projected to the ground with the true attitude (trapezoid, Fig. 5) and re-projected by the
    vertical camera at the same centre (Fig. 6) land where the rotation homography sends them."""
    R_world_cam = matrix_from_euler(roll, pitch, yaw) @ R_BODY_CAMERA_DOWN
    R_world_rcam = matrix_from_euler(0.0, 0.0, yaw) @ R_BODY_CAMERA_DOWN
    corners = CAMERA.corners_px()
    ground = ground_corners(CAMERA.K, R_world_cam, h, corners)
    points_rcam = (np.c_[ground, np.zeros(4)] - [0.0, 0.0, h]) @ R_world_rcam  # world -> rectified camera
    expected = CAMERA.project(points_rcam)
    H = rectifying_homography(CAMERA.K, rectifying_rotation(roll, pitch, R_BODY_CAMERA_DOWN))
    mapped = np.c_[corners, np.ones(4)] @ H.T
    assert np.allclose(mapped[:, :2] / mapped[:, 2:], expected, atol=1e-6)


def test_rectified_frame_matches_a_level_render(texture: GroundTexture) -> None:
    roll, pitch, yaw = math.radians(4.0), math.radians(-3.0), 0.4
    p = np.array([0.3, -0.2, 3.6])
    tilted = render_ground_view(
        texture, CAMERA, *camera_pose_from_body(matrix_from_euler(roll, pitch, yaw), p, R_BODY_CAMERA_DOWN)
    )
    level = render_ground_view(
        texture, CAMERA, *camera_pose_from_body(matrix_from_euler(0.0, 0.0, yaw), p, R_BODY_CAMERA_DOWN)
    )
    rect = rectify_frame(tilted, CAMERA.K, roll, pitch)
    inside = rect.valid_mask > 0
    assert 0.8 < inside.mean() < 1.0
    diff_rect = np.abs(rect.image.astype(float) - level)[inside].mean()
    diff_raw = np.abs(tilted.astype(float) - level)[inside].mean()
    assert diff_rect < 4.0
    assert diff_rect < 0.25 * diff_raw


def test_level_frame_is_unchanged() -> None:
    image = (np.arange(480 * 752) % 251).astype(np.uint8).reshape(480, 752)
    rect = rectify_frame(image, CAMERA.K, 0.0, 0.0, border_px=0)
    assert np.array_equal(rect.image, image)
    assert rect.valid_mask.mean() > 250


def test_bad_inputs() -> None:
    with pytest.raises(InputError):
        rectify_frame(np.zeros((480, 752), dtype=np.float32), CAMERA.K, 0.0, 0.0)
    with pytest.raises(InputError):
        rectify_frame(np.zeros((480, 752, 3), dtype=np.uint8), CAMERA.K, 0.0, 0.0)
    with pytest.raises(RectificationError):
        rectify_frame(np.zeros((480, 752), dtype=np.uint8), CAMERA.K, math.radians(80.0), 0.0)
