"""Localizer service pieces without a network: settings, scene files, VO odometry, the pose message."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.camera import CameraModel
from common.datasets.calibration import CalibrationError, opencv_yaml_text
from common.errors import CapatazError
from common.geometry import (
    R_BODY_CAMERA_FORWARD,
    matrix_from_euler,
    matrix_from_quaternion,
    quaternion_from_euler,
)
from common.localization.model import SceneModelError, scene_to_dict
from common.localization.office import default_scene
from common.localization.pose import CameraPose
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackingStatus
from common.wire.messages import PoseEstimate
from services.localizer import LocalizerSettings, odometry_between, pose_message
from services.localizer.loading import load_scene, localizer_camera
from services.runtime.camera_options import CameraOptions


def _calibrated(path: Path) -> LocalizerSettings:
    return LocalizerSettings(camera=CameraOptions(calibration=path))


def _pose(stamp_s: float, p: list[float], euler: list[float]) -> PoseEstimate:
    return PoseEstimate(
        uav="uav0",
        stamp_s=stamp_s,
        p_world_body_m=np.asarray(p, dtype=float),
        q_world_body=quaternion_from_euler(*euler),
        covariance=np.eye(6),
        source="vo",
    )


def test_vo_odometry_is_the_finite_difference_of_positions_and_wrapped_angles() -> None:
    a = _pose(1.0, [1.0, 2.0, 1.5], [0.0, 0.0, np.radians(179.0)])
    b = _pose(1.5, [1.5, 1.0, 1.5], [0.0, 0.0, np.radians(-179.0)])
    result = odometry_between(a, b)
    assert result is not None
    velocity, rates = result
    assert np.allclose(velocity, [1.0, -2.0, 0.0])
    assert np.allclose(rates, [0.0, 0.0, np.radians(2.0) / 0.5], atol=1e-9)
    assert odometry_between(b, a) is None


def test_model_files_load_and_bad_ones_fail_clearly(tmp_path: Path) -> None:
    path = tmp_path / "office.json"
    path.write_text(json.dumps(scene_to_dict(default_scene())))
    assert load_scene(LocalizerSettings(model=path)).n_edges == default_scene().n_edges
    with pytest.raises(CapatazError, match="not a file"):
        load_scene(LocalizerSettings(model=tmp_path / "missing.json"))
    (tmp_path / "bad.json").write_text('{"vertices": []}')
    with pytest.raises(SceneModelError):
        load_scene(LocalizerSettings(model=tmp_path / "bad.json"))


def test_calibration_file_gives_the_camera(tmp_path: Path) -> None:
    camera = CameraModel(width=640, height=480, fx=600.0, fy=598.0, cx=321.0, cy=239.0)
    (tmp_path / "cam.yaml").write_text(opencv_yaml_text(camera))
    assert localizer_camera(_calibrated(tmp_path / "cam.yaml")) == camera
    (tmp_path / "bad.yaml").write_text("image_width: 640\n")
    with pytest.raises(CalibrationError):
        localizer_camera(_calibrated(tmp_path / "bad.yaml"))


def test_initial_pose_is_camera_from_world_as_rvec_tvec_or_matrix() -> None:
    truth = CameraPose(np.array([0.3, -0.2, 0.5]), matrix_from_euler(-2.0, 0.1, 0.7))
    rvec, tvec = truth.rvec_tvec()
    from_rvec = LocalizerSettings(initial_pose=(*rvec.tolist(), *tvec.tolist())).start_pose()
    from_matrix = LocalizerSettings(initial_pose=tuple(truth.T_camera_world().ravel().tolist())).start_pose()
    for pose in (from_rvec, from_matrix):
        assert np.allclose(pose.p_world_camera_m, truth.p_world_camera_m)
        assert np.allclose(pose.R_world_camera, truth.R_world_camera)
    # OpenCV's convention: the world origin lands at tvec in the camera frame
    R_cw, _ = cv2.Rodrigues(rvec)
    assert np.allclose(R_cw @ np.zeros(3) + tvec, truth.t_camera_world_m)
    with pytest.raises(ValueError, match="6 numbers"):
        LocalizerSettings(initial_pose=(1.0, 2.0, 3.0))
    bad = truth.T_camera_world()
    bad[3] = [0.0, 0.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="last row"):
        LocalizerSettings(initial_pose=tuple(bad.ravel().tolist()))


def test_pose_message_carries_the_body_pose_covariance_and_tracking_state() -> None:
    tracker = ModelTracker(default_scene(), CameraModel.from_hfov(320, 240, 70.0))
    state = tracker.start(CameraPose.from_body_state([5.0, 4.0, 1.5, 0.1, -0.05, 2.0], R_BODY_CAMERA_FORWARD))
    covariance = np.diag([1e-4, 2e-4, 3e-4, 1e-5, 2e-5, 3e-5])
    state = replace(state, covariance=covariance, status=TrackingStatus.LOST)
    message = pose_message("uav0", 7, 3.5, state, R_BODY_CAMERA_FORWARD)
    assert message.seq == 7 and message.source == "pf" and message.tracking_state == "lost"
    assert np.allclose(message.p_world_body_m, [5.0, 4.0, 1.5])
    assert np.allclose(matrix_from_quaternion(message.q_world_body), matrix_from_euler(0.1, -0.05, 2.0))
    assert np.allclose(message.covariance, covariance)


def test_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="particles"):
        LocalizerSettings(particles=1)
    with pytest.raises(ValueError, match="scoring"):
        LocalizerSettings(scoring="best")  # type: ignore[arg-type]
