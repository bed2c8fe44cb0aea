"""Calibration files: OpenCV YAML and ROS camera_info YAML read back; bad files refused in one line."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.calibration import (
    CalibrationError,
    camera_from_camera_info,
    opencv_yaml_text,
    parse_calibration,
    ros_yaml_text,
)
from common.datasets.rig_files import load_rig

CAMERAS = [
    CameraModel(640, 480, 455.2, 456.1, 318.4, 241.9),
    CameraModel(
        320,
        240,
        160.3,
        160.9,
        161.2,
        118.7,
        Distortion(DistortionModel.RADTAN, (-0.3, 0.08, 1e-3, -2e-3, 0.0)),
    ),
    CameraModel(
        320, 240, 170.0, 170.0, 159.5, 119.5, Distortion(DistortionModel.FISHEYE, (-0.01, 0.02, -0.01, 0.002))
    ),
]


@pytest.mark.parametrize("camera", CAMERAS, ids=["pinhole", "radtan", "fisheye"])
@pytest.mark.parametrize("writer", [opencv_yaml_text, ros_yaml_text], ids=["opencv", "ros"])
def test_calibration_files_read_back_the_camera(tmp_path: Path, camera: CameraModel, writer) -> None:
    path = tmp_path / "calib.yaml"
    path.write_text(writer(camera))
    loaded = load_camera_file(path)
    assert (loaded.width, loaded.height) == (camera.width, camera.height)
    np.testing.assert_allclose(loaded.K, camera.K, rtol=1e-12)
    assert loaded.distortion.model is (
        camera.distortion.model if camera.is_distorted else loaded.distortion.model
    )
    np.testing.assert_allclose(
        loaded.project([[0.3, -0.2, 1.0]]), camera.project([[0.3, -0.2, 1.0]]), atol=1e-9
    )


def load_camera_file(path: Path) -> CameraModel:
    """The camera of a calibration file, read the way every ``--calibration`` is (:func:`load_rig`)."""
    return load_rig(path).camera


def test_opencv_calibration_sample_layout_is_read(tmp_path: Path) -> None:
    """The layout OpenCV's own calibration sample writes (extra keys, no distortion_model)."""
    K = np.array([[657.3, 0.0, 302.7], [0.0, 657.7, 242.3], [0.0, 0.0, 1.0]])
    D = np.array([[-0.418, 0.500, 0.0013, -0.0002, -0.583]])
    fs = cv2.FileStorage(str(tmp_path / "out_camera_data.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "Sun Nov 22 2026")
    fs.write("nr_of_frames", 25)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("board_width", 9)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D)
    fs.write("avg_reprojection_error", 0.29)
    fs.release()
    cam = load_camera_file(tmp_path / "out_camera_data.yml")
    np.testing.assert_allclose(cam.K, K)
    assert cam.distortion.model is DistortionModel.RADTAN
    np.testing.assert_allclose(cam.distortion.coeffs, D.ravel())


def test_ros_camera_info_as_written_by_cameracalibrator() -> None:
    text = """image_width: 752
image_height: 480
camera_name: mv_25001498
camera_matrix:
  rows: 3
  cols: 3
  data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [458.654, 0, 367.215, 0, 0, 457.296, 248.375, 0, 0, 0, 1, 0]
"""
    cam = parse_calibration(text)
    assert (cam.width, cam.height, cam.fx, cam.cy) == (752, 480, 458.654, 248.375)
    assert cam.distortion.coeffs[0] == pytest.approx(-0.28340811)


def test_camera_info_message_mapping() -> None:
    cam = camera_from_camera_info(
        320, 240, "equidistant", [0.01, 0.0, 0.0, 0.0], [200, 0, 160, 0, 200, 120, 0, 0, 1]
    )
    assert cam.distortion.model is DistortionModel.FISHEYE


@pytest.mark.parametrize("name", ["equidistant", "fisheye"])
def test_a_fisheye_with_all_zero_coefficients_stays_a_fisheye_not_a_pinhole(name: str) -> None:
    """Regression: zero coefficients made any file a pinhole; a fisheye's zero is the equidistant lens."""
    cam = camera_from_camera_info(320, 240, name, [0.0] * 4, [200, 0, 160, 0, 200, 120, 0, 0, 1])
    assert cam.distortion.model is DistortionModel.FISHEYE and cam.is_distorted
    # a ray 45 deg off the axis lands at f * theta (equidistant), not at f * tan(theta) (pinhole)
    u, _ = cam.project(np.array([[1.0, 0.0, 1.0]]))[0]
    assert u - cam.cx == pytest.approx(200.0 * np.pi / 4.0)
    assert np.allclose(cam.undistort_px(cam.distort_px(np.array([[300.0, 200.0]]))), [[300.0, 200.0]])
    pinhole = camera_from_camera_info(320, 240, "plumb_bob", [0.0] * 5, [200, 0, 160, 0, 200, 120, 0, 0, 1])
    assert pinhole.distortion.model is DistortionModel.NONE  # radtan's zero is a pinhole


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00", "not text"),
        (b"a: [1, 2\n", "not YAML at line"),
        (b"- 1\n- 2\n", "not a mapping"),
        (b"foo: 1\nbar: 2\n", "not a rig file: expected an OpenCV YAML calibration"),
        (
            b"image_width: 640\ncamera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n",
            "image_height",
        ),
        (
            b"image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [1, 0, 0]}\n",
            "3x3 but has 3 values",
        ),
        (
            b"image_width: 640\nimage_height: 480\ndistortion_model: rational_polynomial\n"
            b"distortion_coefficients: {rows: 1, cols: 8, data: [0.1, 0, 0, 0, 0, 0.2, 0, 0]}\n"
            b"camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n",
            "not supported",
        ),
        (
            b"image_width: 640\nimage_height: 480\n"
            b"camera_matrix: {rows: 3, cols: 3, data: [-500, 0, 320, 0, 500, 240, 0, 0, 1]}\n",
            "focal lengths must be positive",
        ),
        (b"%YAML:1.0\n---\nimage_width: 640\n", "without camera_matrix"),
        (b"%YAML:1.0\n---\n  : : [\n", "not an OpenCV YAML"),
    ],
    ids=[
        "binary",
        "broken-yaml",
        "list",
        "unknown-keys",
        "no-height",
        "short-K",
        "rational-polynomial",
        "negative-focal",
        "opencv-no-K",
        "opencv-broken",
    ],
)
def test_bad_calibration_files_are_refused_in_one_line(tmp_path: Path, content: bytes, match: str) -> None:
    path = tmp_path / "calib.yaml"
    path.write_bytes(content)
    with pytest.raises(CalibrationError, match=match) as info:
        load_camera_file(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_a_folder_or_missing_path_is_not_a_calibration(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="not a file"):
        load_camera_file(tmp_path)
    with pytest.raises(CalibrationError, match="not a file"):
        load_camera_file(tmp_path / "missing.yaml")


def test_an_opencv_matrix_whose_data_does_not_fill_it_names_the_file_regression(tmp_path: Path) -> None:
    """Issue 28: a camera_matrix of 3x3 with 6 values gave OpenCV's bare assertion, without the file."""
    path = tmp_path / "short.yaml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 752\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
        "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 400., 0., 0., 400., 1., 2. ]\n"
    )
    with pytest.raises(CalibrationError, match=r"short\.yaml: camera_matrix says 3x3 but has 6 values"):
        load_camera_file(path)


def test_a_yaml_reader_error_is_one_line(tmp_path: Path) -> None:
    """Regression: PyYAML's reader error (a NUL byte) spans two lines; the calibration error is one."""
    path = tmp_path / "nul.yaml"
    path.write_bytes(b"\x00camera_matrix: 1")
    with pytest.raises(CalibrationError) as info:
        load_camera_file(path)
    assert "not YAML" in str(info.value) and "\n" not in str(info.value)
