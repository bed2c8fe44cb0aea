"""The master's yaw options: calibration files (OpenCV YAML, ROS camera_info YAML) and explicit intrinsics
into the yaw settings, and the gyro buffer that feeds the prior."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from common.camera import DistortionModel
from common.datasets.calibration import opencv_yaml_text, ros_yaml_text
from common.errors import InputError
from common.sim.field import wide_angle_camera
from common.wire.messages import ImuSample
from common.yaw import YawSettings, gyro_delta_yaw_rad
from common.yaw.level import R_level_body_from_imu
from services.master.gyro import GyroBuffer, GyroPrior
from services.master.lens import CameraSource, add_yaw_prior_arguments, yaw_prior_settings_from_args
from services.runtime.counters import Counters
from services.runtime.gate import InputGate


def _parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_yaw_prior_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize("writer", [opencv_yaml_text, ros_yaml_text])
def test_calibration_files_of_both_formats_load_into_the_yaw_settings(tmp_path: Path, writer: object) -> None:
    camera = wide_angle_camera()
    path = tmp_path / "camera.yaml"
    path.write_text(writer(camera))  # type: ignore[operator]
    prior = yaw_prior_settings_from_args(_parse("--calibration", str(path), "--max-yaw-rate", "200"))
    settings = prior.tracker_settings(YawSettings(), CameraSource(prior.lens).at(320, 240))
    assert settings.camera is not None and settings.max_yaw_rate_deg_s == 200.0
    assert settings.camera.distortion.model is DistortionModel.RADTAN
    assert np.allclose(settings.camera.K, camera.K)
    assert np.allclose(settings.camera.distortion.coeffs, camera.distortion.coeffs)


def test_explicit_intrinsics_and_distortion_options() -> None:
    prior = yaw_prior_settings_from_args(
        _parse("--fx", "200", "--distortion", "fisheye", "--distortion-coeffs", "0.01,-0.002,0,0")
    )
    camera = CameraSource(prior.lens).at(320, 240)
    assert camera is not None
    assert camera.fy == 200.0 and camera.cx == 159.5 and camera.distortion.model is DistortionModel.FISHEYE
    assert prior.tracker_settings(YawSettings(), camera).camera == camera
    nothing = yaw_prior_settings_from_args(_parse()).lens
    assert CameraSource(nothing).at(320, 240) is None  # nothing set: no lens model


@pytest.mark.parametrize(
    "argv",
    [
        ("--distortion", "radtan"),  # a model without intrinsics
        ("--fx", "100", "--distortion", "radtan", "--distortion-coeffs", "0.1,0.2"),  # 2 of 5 coefficients
        ("--fx", "100", "--distortion-coeffs", "a,b"),
        ("--fx", "-3"),
        ("--max-yaw-rate", "0"),
    ],
)
def test_bad_lens_options_are_one_line_errors(argv: tuple[str, ...]) -> None:
    with pytest.raises(InputError) as info:
        yaw_prior_settings_from_args(_parse(*argv))
    assert "\n" not in str(info.value)


def test_a_calibration_file_that_is_not_one_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "notes.yaml"
    path.write_text("just: some yaml\n")
    with pytest.raises(InputError):
        yaw_prior_settings_from_args(_parse("--calibration", str(path)))
    with pytest.raises(InputError):
        yaw_prior_settings_from_args(_parse("--calibration", str(tmp_path / "missing.yaml")))
    calibrated = tmp_path / "c.yaml"
    calibrated.write_text(opencv_yaml_text(wide_angle_camera()))
    with pytest.raises(InputError):  # a file and explicit values: which one?
        yaw_prior_settings_from_args(_parse("--calibration", str(calibrated), "--fx", "100"))


def _imu(stamp_s: float, rate: float) -> ImuSample:
    return ImuSample(
        uav="uav0", stamp_s=stamp_s, gyro_rad_s=np.array([0.0, 0.0, rate]), accel_m_s2=np.zeros(3)
    )


def test_gyro_buffer_gives_the_in_process_bits_and_refuses_disorder() -> None:
    stamps = np.arange(0.0, 1.0, 0.0025)
    rates = np.sin(stamps * 7.0)
    buffer = GyroBuffer(capacity=100)
    for t, r in zip(stamps, rates, strict=True):
        assert buffer.add(_imu(float(t), float(r)))
    assert len(buffer) <= 200  # bounded
    gyro = np.stack([np.zeros_like(rates), np.zeros_like(rates), rates], axis=1)
    expected = gyro_delta_yaw_rad(stamps, gyro, 0.90, 0.95)
    assert buffer.delta_rad(0.90, 0.95) == expected
    assert buffer.delta_rad(0.10, 0.15) is None  # long gone
    assert not buffer.add(_imu(0.95, 1.0))  # not newer than the newest
    assert buffer.out_of_order == 1
    assert buffer.add(_imu(0.0, 0.5))  # older than everything: the stream restarted
    assert len(buffer) == 1


def test_gyro_buffer_gives_the_in_process_tilt_bits_regression() -> None:
    """The master's tilt for its level views is the in-process one on the same samples (to the bit); a
    window less than half covered by samples gives none, in both."""
    stamps = np.arange(0.0, 5.0, 0.0025)
    roll = 0.05 * np.sin(stamps)
    gyro = np.stack([0.05 * np.cos(stamps), np.zeros_like(stamps), 0.3 * np.ones_like(stamps)], axis=1)
    accel = np.stack([np.zeros_like(stamps), 9.81 * np.sin(roll), 9.81 * np.cos(roll)], axis=1)
    R_body_imu = np.diag([1.0, -1.0, -1.0])
    buffer = GyroBuffer(capacity=1000)
    for t, w, a in zip(stamps, gyro, accel, strict=True):
        assert buffer.add(ImuSample(uav="uav0", stamp_s=float(t), gyro_rad_s=w, accel_m_s2=a))
    tilt = buffer.tilt(4.9, R_body_imu)
    assert tilt is not None
    assert np.array_equal(tilt, R_level_body_from_imu(stamps, gyro, accel, 4.9, R_body_imu))
    assert buffer.tilt(1.0, R_body_imu) is None  # 1 s of a 3 s window
    assert R_level_body_from_imu(stamps, gyro, accel, 1.0, R_body_imu) is None


class _Service:
    """What the input gate counts and logs with."""

    def __init__(self) -> None:
        self.counters = Counters()

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None:
        self.counters.inc(counter)


def test_mount_options_turn_the_gyro_prior_about_the_images_axis_on_the_imus_clock() -> None:
    """A down camera on an IMU mounted upside down, its clock 12 ms ahead: the prior integrates the IMU's
    -z between the frame stamps plus 12 ms, and equals the body-aligned IMU's prior of the same motion."""
    upside_down = "1,0,0,0,-1,0,0,0,-1"
    prior = yaw_prior_settings_from_args(_parse("--imu-axes", upside_down, "--imu-time-offset", "0.012"))
    assert np.allclose(prior.gyro_axis_imu(), [0.0, 0.0, -1.0])
    stamps = np.arange(0.0, 1.0, 0.0025)
    rates = np.sin(stamps * 7.0)
    service = _Service()
    gate = InputGate("uav0", service)
    gyro = GyroPrior(
        True, 0.0, service.counters, gate, prior.gyro_axis_imu(), prior.rig_mount.imu_time_offset_s
    )
    aligned = GyroBuffer()
    for t, r in zip(stamps, rates, strict=True):
        gyro.on_sample(_imu(float(t) + 0.012, -float(r)))  # the IMU's -z reads the body's +z
        aligned.add(_imu(float(t), float(r)))
    counts: dict[str, int] = {}
    delta = gyro.delta_rad(0.50, 0.55, counts)
    assert delta == pytest.approx(aligned.delta_rad(0.50, 0.55), abs=1e-12) and counts == {"gyro_prior": 1}
    assert delta is not None and abs(delta) > 0.01
    default = yaw_prior_settings_from_args(_parse())
    assert (
        np.allclose(default.gyro_axis_imu(), [0.0, 0.0, 1.0]) and default.rig_mount.imu_time_offset_s == 0.0
    )
    # a camera tilted 10 deg backward (about body y): a yaw turns its image by cos(10 deg), and its pitch rate
    # does not (the optical axis leans, the prior's weights do not: common.yaw.mount)
    c, s = np.cos(np.radians(10.0)), np.sin(np.radians(10.0))
    tilted = (
        np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        @ np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    ).ravel()
    leaning = yaw_prior_settings_from_args(_parse("--mount", ",".join(f"{v:.17g}" for v in tilted)))
    assert np.allclose(leaning.gyro_axis_imu(), [0.0, 0.0, c])


@pytest.mark.parametrize(
    "argv",
    [
        ("--mount", "sideways"),
        ("--mount", "forward"),  # the yaw core needs a camera looking down
        ("--mount", "1,0,0,0,1,0,0,0"),  # 8 numbers
        ("--imu-axes", "1,0,0,0,1,0,0,0,-1"),  # a reflection
        ("--imu-axes", "2,0,0,0,1,0,0,0,1"),  # not orthonormal
        ("--imu-time-offset", "5"),
    ],
)
def test_bad_mount_options_are_one_line_errors(argv: tuple[str, ...]) -> None:
    with pytest.raises(InputError) as info:
        yaw_prior_settings_from_args(_parse(*argv))
    assert "\n" not in str(info.value)


def test_level_views_are_asked_for_and_kept_only_for_a_stream_with_a_lens() -> None:
    """``--level-views`` (off by default) levels a stream's pairs only when its lens is known; the tilt is
    counted at each frame (none before the IMU's window has half filled)."""
    assert not yaw_prior_settings_from_args(_parse()).level_views
    prior = yaw_prior_settings_from_args(_parse("--level-views"))
    service = _Service()
    gyro = GyroPrior.of(prior, service.counters, InputGate("uav0", service), "master")
    axis, R_body_imu = prior.gyro_axis_imu(), prior.rig_mount.R_body_imu
    gyro.for_stream(axis, 0.0, R_body_imu, False, "master")  # no intrinsics: no level views
    counts: dict[str, int] = {}
    assert not gyro.level and gyro.tilt(1.0, counts) is None and counts == {}
    gyro.for_stream(axis, 0.0, R_body_imu, True, "master")
    assert gyro.level
    for t in np.arange(0.0, 2.0, 0.0025):
        gyro.on_sample(
            ImuSample(
                uav="uav0", stamp_s=float(t), gyro_rad_s=np.zeros(3), accel_m_s2=np.array([0.0, 0.0, 9.81])
            )
        )
    assert gyro.tilt(1.0, counts) is None and counts == {"no_tilt": 1}
    tilt = gyro.tilt(1.99, counts)
    assert tilt is not None and np.allclose(tilt, np.eye(3)) and counts == {"no_tilt": 1, "tilt": 1}
