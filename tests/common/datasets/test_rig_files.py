"""Rig files: the capataz rig YAML round trip, OpenCV / ROS calibrations, EuRoC sensor.yaml, Kalibr camchain;
every bad file refused in one line naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.calibration import opencv_yaml_text, ros_yaml_text
from common.datasets.rig_files import RigFileError, load_rig, parse_rig, rig_yaml_text, write_rig
from common.geometry import R_BODY_CAMERA_DOWN, R_BODY_CAMERA_FORWARD
from common.rig import Rig
from tests.common.rigs import rigs

#: EuRoC MAV dataset (Burri et al., IJRR 2016), MH_01_easy/mav0/cam0/sensor.yaml as published (the copy in
#: ../shared/data is used too when present: test_euroc_files_in_the_shared_data_read).
EUROC_CAM0 = """%YAML:1.0
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
         0.0, 0.0, 0.0, 1.0]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""
EUROC_T_BS = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)

#: Kalibr's documented example chain (https://github.com/ethz-asl/kalibr/wiki/yaml-formats, "Example
#: chain.yaml"), cam0 of it.
KALIBR_CAMCHAIN = """cam0:
  camera_model: pinhole
  intrinsics: [461.629, 460.152, 362.680, 246.049]
  distortion_model: radtan
  distortion_coeffs: [-0.27695497, 0.06712482, 0.00087538, 0.00011556]
  T_cam_imu:
  - [0.01779318, 0.99967549,-0.01822936, 0.07008565]
  - [-0.9998017, 0.01795239, 0.00860714,-0.01771023]
  - [0.00893160, 0.01807260, 0.99979678, 0.00399246]
  - [0.0, 0.0, 0.0, 1.0]
  timeshift_cam_imu: -8.121e-05
  rostopic: /cam0/image_raw
  resolution: [752, 480]
"""
KALIBR_T_CAM_IMU = np.array(
    [
        [0.01779318, 0.99967549, -0.01822936, 0.07008565],
        [-0.9998017, 0.01795239, 0.00860714, -0.01771023],
        [0.00893160, 0.01807260, 0.99979678, 0.00399246],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
FISHEYE = CameraModel(
    320, 240, 170.0, 170.0, 159.5, 119.5, Distortion(DistortionModel.FISHEYE, (-0.01, 0.02, -0.01, 0.002))
)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _size_and_intrinsics(camera: CameraModel) -> tuple[float, ...]:
    return (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)


def test_euroc_sensor_yaml_gives_the_camera_and_its_mount(tmp_path: Path) -> None:
    rig = load_rig(_write(tmp_path, "sensor.yaml", EUROC_CAM0))
    assert _size_and_intrinsics(rig.camera) == (752, 480, 458.654, 457.296, 367.215, 248.375)
    assert rig.camera.distortion.model is DistortionModel.RADTAN
    assert rig.camera.distortion.coeffs == (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0)
    assert np.array_equal(rig.R_body_camera, EUROC_T_BS[:3, :3])
    assert np.array_equal(rig.t_body_camera_m, EUROC_T_BS[:3, 3])
    assert np.array_equal(rig.R_body_imu, np.eye(3)) and rig.time_offset_s == 0.0
    # EuRoC's cam0 looks along the IMU's +z (its optical axis is the body's z within 1.5 deg)
    assert rig.R_body_camera[2, 2] > np.cos(np.radians(1.5))


def test_euroc_files_in_the_shared_data_read(shared_data: Path) -> None:
    files = sorted(shared_data.glob("**/mav0/cam*/sensor.yaml"))
    if not files:
        pytest.skip(f"no EuRoC sensor.yaml under {shared_data} (its README lists no EuRoC sequence)")
    for path in files:
        rig = load_rig(path)
        assert rig.camera.width > 0 and np.isfinite(rig.t_body_camera_m).all()


def test_kalibr_camchain_is_inverted_into_the_body_imu_frame(tmp_path: Path) -> None:
    rig = load_rig(_write(tmp_path, "camchain-imucam.yaml", KALIBR_CAMCHAIN))
    assert _size_and_intrinsics(rig.camera) == (752, 480, 461.629, 460.152, 362.680, 246.049)
    assert rig.camera.distortion.coeffs == (-0.27695497, 0.06712482, 0.00087538, 0.00011556, 0.0)
    assert rig.time_offset_s == -8.121e-05  # Kalibr's t_imu = t_cam + shift: the same sign as the rig's
    assert np.array_equal(rig.R_body_imu, np.eye(3))
    # a point given in the camera frame, moved into the body (IMU) frame by the rig, maps back by T_cam_imu
    # (to the example rotation's own orthonormality, 2e-7)
    p_camera = np.array([0.3, -0.2, 1.7])
    p_imu = rig.R_body_camera @ p_camera + rig.t_body_camera_m
    np.testing.assert_allclose(
        KALIBR_T_CAM_IMU[:3, :3] @ p_imu + KALIBR_T_CAM_IMU[:3, 3], p_camera, atol=1e-6
    )
    # and the inverse is not the forward transform: the camera sits 7 cm from the IMU, not at its origin
    assert np.linalg.norm(rig.t_body_camera_m) == pytest.approx(
        np.linalg.norm(KALIBR_T_CAM_IMU[:3, 3]), abs=1e-6
    )
    assert not np.allclose(rig.t_body_camera_m, KALIBR_T_CAM_IMU[:3, 3], atol=1e-3)


def test_kalibr_equidistant_lens_is_a_fisheye_and_a_camera_only_chain_has_the_default_mount(
    tmp_path: Path,
) -> None:
    text = KALIBR_CAMCHAIN.replace("distortion_model: radtan", "distortion_model: equidistant")
    text = text.replace("[-0.27695497, 0.06712482, 0.00087538, 0.00011556]", "[-0.01, 0.02, -0.01, 0.002]")
    text = "\n".join(
        line for line in text.splitlines() if not line.startswith("  - ") and "T_cam_imu" not in line
    )
    text = text.replace("timeshift_cam_imu: -8.121e-05", "")
    rig = load_rig(_write(tmp_path, "camchain.yaml", text))
    assert rig.camera.distortion == Distortion(DistortionModel.FISHEYE, (-0.01, 0.02, -0.01, 0.002))
    assert rig == Rig(rig.camera)


@pytest.mark.parametrize("writer", [opencv_yaml_text, ros_yaml_text], ids=["opencv", "ros"])
def test_a_camera_calibration_is_a_rig_with_the_default_mount(tmp_path: Path, writer) -> None:
    rig = load_rig(_write(tmp_path, "calib.yaml", writer(FISHEYE)))
    assert rig == Rig(FISHEYE)
    assert np.array_equal(rig.R_body_camera, R_BODY_CAMERA_DOWN)


def test_the_capataz_rig_file_is_an_opencv_calibration_with_mount_keys(tmp_path: Path) -> None:
    rig = Rig(
        FISHEYE,
        R_body_camera=R_BODY_CAMERA_FORWARD,
        t_body_camera_m=np.array([0.1, 0.0, -0.05]),
        time_offset_s=0.004,
    )
    path = write_rig(rig, tmp_path / "rig.yaml")
    text = path.read_text()
    assert text.startswith("%YAML") and "R_body_camera: !!opencv-matrix" in text and "time_offset_s:" in text
    assert load_rig(path) == rig and load_rig(path).rig_id == rig.rig_id


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rig=rigs())
def test_write_then_load_gives_the_same_rig_and_id(tmp_path: Path, rig: Rig) -> None:
    loaded = load_rig(write_rig(rig, tmp_path / "rig.yaml"))
    assert loaded == rig
    assert loaded.rig_id == rig.rig_id
    assert parse_rig(rig_yaml_text(loaded)) == rig


def _capataz(mount: str) -> str:
    return opencv_yaml_text(FISHEYE) + mount


def _matrix(name: str, rows: int, cols: int, data: str) -> str:
    return f"{name}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n"


BAD_FILES: list[tuple[str, str | bytes, str]] = [
    ("euroc-no-resolution", EUROC_CAM0.replace("resolution: [752, 480]", ""), "missing resolution"),
    (
        "euroc-no-T_BS",
        EUROC_CAM0.split("T_BS:")[0] + "rate_hz: 20\nresolution: [752, 480]\nintrinsics: [1, 1, 1, 1]",
        "missing T_BS",
    ),
    (
        "euroc-T_BS-3x4",
        EUROC_CAM0.replace("  cols: 4\n  rows: 4", "  cols: 4\n  rows: 3").replace(
            "\n         0.0, 0.0, 0.0, 1.0]", "]"
        ),
        "T_BS must be 4x4",
    ),
    (
        "euroc-T_BS-count",
        EUROC_CAM0.replace("\n         0.0, 0.0, 0.0, 1.0]", "]"),
        "T_BS says 4x4 but has 12 values",
    ),
    ("euroc-T_BS-scaled", EUROC_CAM0.replace("0.999660727178", "1.999660727178"), "not orthonormal"),
    ("euroc-T_BS-row", EUROC_CAM0.replace("0.0, 0.0, 0.0, 1.0]", "0.0, 0.0, 0.0, 2.0]"), "last row"),
    ("euroc-nan", EUROC_CAM0.replace("458.654", ".nan"), "intrinsics must be finite"),
    ("euroc-3-intrinsics", EUROC_CAM0.replace("458.654, ", ""), "intrinsics must be [fu, fv, cu, cv]"),
    ("euroc-resolution", EUROC_CAM0.replace("[752, 480]", "[752]"), "resolution must be [width, height]"),
    ("euroc-resolution-real", EUROC_CAM0.replace("[752, 480]", "[752.5, 480]"), "must be an integer"),
    ("euroc-lens", EUROC_CAM0.replace("radial-tangential", "omni-radtan"), "not supported"),
    ("kalibr-omni", KALIBR_CAMCHAIN.replace("camera_model: pinhole", "camera_model: omni"), "pinhole only"),
    ("kalibr-nan", KALIBR_CAMCHAIN.replace("0.07008565", ".nan"), "T_cam_imu must be finite"),
    ("kalibr-T-3-rows", KALIBR_CAMCHAIN.replace("  - [0.0, 0.0, 0.0, 1.0]\n", ""), "T_cam_imu must be 4x4"),
    (
        "kalibr-T-scalar",
        KALIBR_CAMCHAIN.split("  T_cam_imu:")[0] + "  T_cam_imu: 1\n  resolution: [752, 480]\n",
        "list of 4 rows",
    ),
    (
        "kalibr-reflection",
        KALIBR_CAMCHAIN.replace(
            "[0.00893160, 0.01807260, 0.99979678", "[-0.00893160, -0.01807260, -0.99979678"
        ),
        "reflection",
    ),
    ("kalibr-timeshift", KALIBR_CAMCHAIN.replace("-8.121e-05", "soon"), "timeshift_cam_imu must be a number"),
    ("kalibr-offset-units", KALIBR_CAMCHAIN.replace("-8.121e-05", "-8121"), "time_offset_s"),
    (
        "capataz-R-2x2",
        _capataz(_matrix("R_body_camera", 2, 2, "1., 0., 0., 1.")),
        "R_body_camera must be 3x3",
    ),
    (
        "capataz-R-reflection",
        _capataz(_matrix("R_body_imu", 3, 3, "1., 0., 0., 0., 1., 0., 0., 0., -1.")),
        "R_body_imu has determinant -1",
    ),
    ("capataz-t-2", _capataz(_matrix("t_body_camera_m", 2, 1, "1., 0.")), "t_body_camera_m must be 3"),
    (
        "capataz-t-nan",
        _capataz(_matrix("t_body_camera_m", 3, 1, ".nan, 0., 0.")),
        "t_body_camera_m must be finite",
    ),
    ("capataz-offset-text", _capataz('time_offset_s: "late"\n'), "time_offset_s is not a number"),
    (
        "capataz-no-K",
        "%YAML:1.0\n---\n" + _matrix("R_body_camera", 3, 3, "1., 0., 0., 0., 1., 0., 0., 0., 1."),
        "without camera_matrix",
    ),
    ("not-yaml", "cam0: [1, 2\n", "not YAML"),
    ("a-list", "- 1\n- 2\n", "not a mapping"),
    ("empty", "", "not a mapping"),
    ("unknown-keys", "focal: 3\nsize: 4\n", "not a rig file"),
    ("binary", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "not text"),
    ("nul-bytes", b"\x00\x01\x02 not a rig", "not YAML"),
]


@pytest.mark.parametrize(("name", "content", "message"), BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_a_bad_file_is_one_rig_file_error_naming_it(
    tmp_path: Path, name: str, content: str | bytes, message: str
) -> None:
    path = tmp_path / f"{name}.yaml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(RigFileError) as info:
        load_rig(path)
    text = str(info.value)
    assert str(path) in text and message in text and "\n" not in text, text


def test_a_missing_file_or_a_folder_is_refused(tmp_path: Path) -> None:
    for path in (tmp_path / "absent.yaml", tmp_path):
        with pytest.raises(RigFileError, match=f"rig file {path}: not a file"):
            load_rig(path)
