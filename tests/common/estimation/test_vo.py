"""Visual odometry (paper C Algorithms 1-2, eqs. 9-10) on rendered views of the simulator's ground."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.homography import (
    VoError,
    calibrated_homography,
    choose_decomposition,
    decompose_with_known_normal,
    rotation_about_optical_axis,
)
from common.estimation.vo import (
    SUBPIXEL_FLOW_PX,
    SUBPIXEL_OVER_READ,
    MotionModel,
    VoPose,
    VoSettings,
    compose_pose,
    estimate_relative_motion,
    median_flow_px,
    metric_translation,
    prepare_frame,
    subpixel_over_read,
)
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    matrix_from_euler,
    matrix_from_quaternion,
    quaternion_from_rotation_vector,
)
from common.sim.ground import GroundTexture, camera_pose_from_body, render_ground_view

CAMERA = CameraModel.default()
SETTINGS = VoSettings()


def _view(texture: GroundTexture, euler: tuple[float, float, float], p: tuple[float, float, float]):
    pose = camera_pose_from_body(matrix_from_euler(*euler), np.array(p), R_BODY_CAMERA_DOWN)
    return render_ground_view(texture, CAMERA, *pose), pose


def test_recovers_a_tilted_pair_and_composes_eqs_9_10(texture: GroundTexture) -> None:
    img0, (R0, c0) = _view(texture, (0.03, -0.02, 0.3), (0.0, 0.0, 3.5))
    img1, (R1, c1) = _view(texture, (0.035, -0.015, 0.32), (0.03, 0.012, 3.51))
    f0 = prepare_frame(img0, None, SETTINGS)
    f1 = prepare_frame(img1, None, SETTINGS)
    motion = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS)
    R_true = R1.T @ R0
    t_true = R1.T @ (c0 - c1)
    angle_err = np.linalg.norm(cv2.Rodrigues(motion.R_k_km1 @ R_true.T)[0])
    assert angle_err < math.radians(0.01)
    t = metric_translation(motion.t_over_d, 3.5)
    assert np.linalg.norm(t - t_true) < 5e-4  # half a millimetre on a 3 cm move
    assert motion.normal_km1 @ (R0.T @ [0.0, 0.0, -1.0]) > 0.999
    pose = compose_pose(VoPose(R0, c0), motion.R_k_km1, t)
    assert np.linalg.norm(pose.p_n_camera_m - c1) < 5e-4
    assert motion.n_inliers >= 0.9 * motion.n_tracked


def test_level_model_on_level_views(texture: GroundTexture) -> None:
    img0, (R0, c0) = _view(texture, (0.0, 0.0, 1.0), (0.5, 0.5, 4.0))
    img1, (R1, c1) = _view(texture, (0.0, 0.0, 1.015), (0.52, 0.49, 4.01))
    motion = estimate_relative_motion(
        prepare_frame(img0, None, SETTINGS), prepare_frame(img1, None, SETTINGS), CAMERA.K, SETTINGS,
        model=MotionModel.LEVEL,
    )  # fmt: skip
    dyaw = math.atan2(motion.R_k_km1[1, 0], motion.R_k_km1[0, 0])
    R_true = R1.T @ R0
    assert dyaw == pytest.approx(math.atan2(R_true[1, 0], R_true[0, 0]), abs=1e-4)
    assert np.linalg.norm(metric_translation(motion.t_over_d, 4.0) - R1.T @ (c0 - c1)) < 5e-4


def test_tiny_translation_is_not_lost(texture: GroundTexture) -> None:
    """OpenCV calls |t/d| < ~5e-4 a pure rotation; the known-normal fallback keeps the 1 mm move."""
    img0, (_, c0) = _view(texture, (0.0, 0.0, 0.0), (0.0, 0.0, 3.5))
    img1, (R1, c1) = _view(texture, (0.0, 0.0, 0.0), (0.001, 0.0, 3.5))
    motion = estimate_relative_motion(
        prepare_frame(img0, None, SETTINGS), prepare_frame(img1, None, SETTINGS), CAMERA.K, SETTINGS
    )
    t = metric_translation(motion.t_over_d, 3.5)
    assert np.linalg.norm(t - R1.T @ (c0 - c1)) < 2e-4


rot = st.floats(-0.05, 0.05)


@settings(deadline=None)
@given(
    rot,
    rot,
    rot,
    st.floats(-0.05, 0.05),
    st.floats(-0.05, 0.05),
    st.floats(-0.02, 0.02),
    st.floats(0.5, 20.0),
)
def test_known_normal_decomposition_is_exact(
    rx: float, ry: float, rz: float, tx: float, ty: float, tz: float, scale: float
) -> None:
    R = matrix_from_quaternion(quaternion_from_rotation_vector([rx, ry, rz]))
    n = np.array([0.05, -0.03, 1.0])
    n /= np.linalg.norm(n)
    t = np.array([tx, ty, tz])
    H_px = scale * CAMERA.K @ (R + np.outer(t, n)) @ np.linalg.inv(CAMERA.K)
    R_est, t_est = decompose_with_known_normal(calibrated_homography(H_px, CAMERA.K), n)
    assert np.allclose(R_est, R, atol=1e-9)
    assert np.allclose(t_est, t, atol=1e-9)


def test_choose_decomposition_prefers_the_ground_normal() -> None:
    R = matrix_from_euler(0.01, 0.0, 0.02)
    t = np.array([0.01, 0.004, 0.001])
    n = np.array([0.0, 0.0, 1.0])
    H = CAMERA.K @ (R + np.outer(t, n)) @ np.linalg.inv(CAMERA.K)
    _, Rs, ts, ns = cv2.decomposeHomographyMat(H, CAMERA.K)
    pts0 = np.array([[100.0, 100.0], [600.0, 120.0], [400.0, 400.0], [200.0, 300.0]])
    p = np.c_[pts0, np.ones(4)] @ H.T
    pts1 = p[:, :2] / p[:, 2:]
    best = choose_decomposition(Rs, ts, ns, CAMERA.K, pts0, pts1, n)
    assert np.allclose(np.ravel(ns[best]), n, atol=1e-6)
    assert np.allclose(np.ravel(ts[best]), t, atol=1e-6)


@settings(deadline=None)  # no wall-clock limit: the suite runs on busy hosts
@given(
    st.lists(
        st.tuples(rot, rot, rot, st.floats(-0.05, 0.05), st.floats(-0.05, 0.05)), min_size=1, max_size=10
    )
)
def test_composition_of_true_relative_motions_reproduces_the_path(steps: list[tuple[float, ...]]) -> None:
    R = matrix_from_euler(0.0, 0.0, 0.3) @ R_BODY_CAMERA_DOWN
    c = np.array([1.0, 2.0, 3.0])
    pose = VoPose(R, c)
    for rx, ry, rz, dx, dy in steps:
        R_next = R @ matrix_from_quaternion(quaternion_from_rotation_vector([rx, ry, rz]))
        c_next = c + np.array([dx, dy, 0.0])
        pose = compose_pose(pose, R_next.T @ R, R_next.T @ (c - c_next))
        R, c = R_next, c_next
        assert np.allclose(pose.R_n_camera, R, atol=1e-9)
        assert np.allclose(pose.p_n_camera_m, c, atol=1e-9)


def test_featureless_frames_fail_cleanly() -> None:
    blank = np.full((480, 752), 128, dtype=np.uint8)
    f = prepare_frame(blank, None, SETTINGS)
    with pytest.raises(VoError):
        estimate_relative_motion(f, f, CAMERA.K, SETTINGS)
    with pytest.raises(InputError):
        metric_translation([0.0, 0.0, 0.0], 0.0)
    with pytest.raises(InputError):
        VoSettings(lk_window_px=4)


def test_known_normal_model_handles_a_pure_climb(texture: GroundTexture) -> None:
    """Translation along the plane normal is the ill-conditioned case of the free decomposition; with the
    normal known (a rectified pair) the 5 mm climb comes out within 0.3 mm, the free one much worse."""
    img0, (_, c0) = _view(texture, (0.0, 0.0, 0.7), (0.3, 0.2, 3.5))
    img1, (R1, c1) = _view(texture, (0.0, 0.0, 0.7), (0.3, 0.2, 3.505))
    f0, f1 = prepare_frame(img0, None, SETTINGS), prepare_frame(img1, None, SETTINGS)
    t_true = R1.T @ (c0 - c1)
    known = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS, model=MotionModel.KNOWN_NORMAL)
    free = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS, model=MotionModel.FREE)
    err_known = np.linalg.norm(metric_translation(known.t_over_d, 3.5) - t_true)
    err_free = np.linalg.norm(metric_translation(free.t_over_d, 3.5) - t_true)
    assert err_known < 3e-4
    assert err_known < 0.5 * err_free
    assert np.allclose(known.t_over_d_free, free.t_over_d)


def test_pyrdown_feature_coordinates_are_not_shifted_by_half_a_pixel() -> None:
    """Regression: features detected on the pyrDown level were mapped to ``2i + 0.5`` (pyrDown's kernel is
    centred on ``2i``). The half-pixel offset biased every pair's translation by ~40 um on flight (b)
    (about 0.003 px per pair, systematic in the camera frame: 3 cm over the flight)."""
    y, x = np.mgrid[0:120, 0:160].astype(np.float64)
    blob = (60.0 + 150.0 * np.exp(-((x - 80.0) ** 2 + (y - 60.0) ** 2) / 8.0)).astype(np.uint8)
    for level in (0, 1):
        settings = VoSettings(detect_level=level, max_features=8, block_size_px=3)
        features = prepare_frame(blob, None, settings).features_px.reshape(-1, 2)
        assert len(features) == 1
        assert np.allclose(features[0], [80.0, 60.0], atol=1e-6), (level, features)


def test_level_free_yaw_model_takes_the_free_rotation_and_the_similarity_translation(
    texture: GroundTexture,
) -> None:
    img0, (_, c0) = _view(texture, (0.0, 0.0, 1.0), (0.5, 0.5, 4.0))
    img1, (R1, c1) = _view(texture, (0.0, 0.0, 1.015), (0.52, 0.49, 3.99))
    f0, f1 = prepare_frame(img0, None, SETTINGS), prepare_frame(img1, None, SETTINGS)
    hybrid = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS, model=MotionModel.LEVEL_FREE_YAW)
    level = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS, model=MotionModel.LEVEL)
    free = estimate_relative_motion(f0, f1, CAMERA.K, SETTINGS, model=MotionModel.FREE)
    assert np.allclose(hybrid.t_over_d, level.t_over_d)
    assert np.allclose(hybrid.R_k_km1, rotation_about_optical_axis(free.R_k_km1))
    assert np.allclose(hybrid.normal_km1_free, free.normal_km1)
    assert np.linalg.norm(metric_translation(hybrid.t_over_d, 4.0) - R1.T @ (c0 - c1)) < 5e-4


@given(st.floats(0.0, 10.0), st.floats(0.0, 10.0))
def test_the_over_read_share_falls_with_the_flow_and_is_zero_from_a_pixel(a: float, b: float) -> None:
    """The tracker over-reads sub-pixel motion (``capataz bench flow``): the share never grows with the
    flow, is the measured one at each measured shift, and is 0 from 1 px on and for an unknown flow."""
    low, high = sorted((a, b))
    assert subpixel_over_read(low) >= subpixel_over_read(high) >= 0.0
    if high >= 1.0:
        assert subpixel_over_read(high) == 0.0
    for flow, share in zip(SUBPIXEL_FLOW_PX, SUBPIXEL_OVER_READ, strict=True):
        assert subpixel_over_read(flow) == pytest.approx(share)
    assert subpixel_over_read(math.nan) == 0.0 and subpixel_over_read(-1.0) == SUBPIXEL_OVER_READ[0]


def test_the_median_flow_is_how_far_the_homography_moves_the_features() -> None:
    features = np.array([[[10.0, 20.0]], [[300.0, 40.0]], [[500.0, 400.0]]], dtype=np.float32)
    shift = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]])
    assert median_flow_px(shift, features) == pytest.approx(5.0)
    turn = np.array(
        [[math.cos(0.01), -math.sin(0.01), 0.0], [math.sin(0.01), math.cos(0.01), 0.0], [0, 0, 1]]
    )
    radii = np.linalg.norm(features.reshape(-1, 2), axis=1)
    assert median_flow_px(turn, features) == pytest.approx(np.median(2.0 * radii * math.sin(0.005)))
    assert median_flow_px(shift, np.zeros((0, 1, 2), dtype=np.float32)) == 0.0
