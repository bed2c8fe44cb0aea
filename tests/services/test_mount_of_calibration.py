"""A ``--calibration`` rig file's mount reaches the master's gyro prior and the estimator (issue 26: a
calibration given to a consumer carried only its camera; EuRoC/Kalibr files were refused by consumers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.camera import CameraModel
from common.datasets.calibration import opencv_yaml_text
from common.datasets.rig_files import write_rig
from common.geometry import R_BODY_CAMERA_DOWN
from common.rig import Rig
from common.yaw.mount import image_turn_axis_imu
from services.estimator.settings import configured_rig
from services.estimator.settings import settings_from_args as estimator_from_args
from services.master.lens import yaw_prior_settings_from_args
from services.runtime.usage import UsageError
from services.tools.cli import build_parser, main

CAMERA = CameraModel.from_hfov(752, 480, 90.0)


def _rot_x(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


MOUNTED = Rig(
    CAMERA,
    R_body_camera=_rot_x(12.0) @ R_BODY_CAMERA_DOWN,
    t_body_camera_m=np.array([0.05, 0.0, -0.02]),
    R_body_imu=_rot_z(90.0),
    time_offset_s=0.004,
)


def test_the_master_takes_the_mount_of_its_calibration_rig_file(tmp_path: Path) -> None:
    path = write_rig(MOUNTED, tmp_path / "rig.yaml")
    prior = yaw_prior_settings_from_args(build_parser().parse_args(["master", "--calibration", str(path)]))
    assert np.allclose(prior.rig_mount.R_body_camera, MOUNTED.R_body_camera, atol=1e-15)
    assert np.allclose(prior.rig_mount.R_body_imu, MOUNTED.R_body_imu, atol=1e-15)
    assert prior.rig_mount.imu_time_offset_s == MOUNTED.time_offset_s
    assert np.allclose(
        prior.gyro_axis_imu(), image_turn_axis_imu(MOUNTED.R_body_camera, MOUNTED.R_body_imu), atol=1e-12
    )


def test_the_estimator_takes_the_camera_and_mount_of_its_calibration_rig_file(tmp_path: Path) -> None:
    path = write_rig(MOUNTED, tmp_path / "rig.yaml")
    settings = estimator_from_args(build_parser().parse_args(["estimator", "--calibration", str(path)]))
    rig = configured_rig(settings)
    assert rig.camera == CAMERA
    assert np.allclose(rig.R_body_camera, MOUNTED.R_body_camera, atol=1e-15)
    assert np.allclose(rig.R_body_imu, MOUNTED.R_body_imu, atol=1e-15)
    assert rig.time_offset_s == MOUNTED.time_offset_s


def test_a_plain_calibration_keeps_the_mount_options(tmp_path: Path) -> None:
    path = tmp_path / "camera.yaml"
    path.write_text(opencv_yaml_text(CAMERA))
    argv = ["estimator", "--calibration", str(path), "--imu-axes", "0,-1,0,1,0,0,0,0,1"]
    rig = configured_rig(estimator_from_args(build_parser().parse_args(argv)))
    assert rig.camera == CAMERA
    assert np.allclose(rig.R_body_imu, _rot_z(90.0), atol=1e-15)
    assert np.array_equal(rig.R_body_camera, R_BODY_CAMERA_DOWN)


@pytest.mark.parametrize("command", ["master", "estimator"])
def test_a_mount_given_in_the_file_and_as_options_is_one_usage_line(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_rig(MOUNTED, tmp_path / "rig.yaml")
    argv = [command, "--calibration", str(path), "--imu-time-offset", "0.01"]
    with pytest.raises(UsageError, match="carries a mount already"):
        if command == "master":
            yaw_prior_settings_from_args(build_parser().parse_args(argv))
        else:
            estimator_from_args(build_parser().parse_args(argv))
    assert main([*argv, "--uav", "u1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--mount" in err and "rig.yaml" in err, err
