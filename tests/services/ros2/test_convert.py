"""The pure conversions of the bridge: stamps, quaternion order, covariance layouts, frame ids, the mount, and
the refusals of ROS sensor messages that cannot be capataz samples (no ROS needed: duck-typed messages)."""

from __future__ import annotations

import array
from types import SimpleNamespace as Ns
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.errors import InputError
from common.geometry import (
    R_BODY_CAMERA_DOWN,
    matrix_from_quaternion,
    normalize_quaternion,
    quaternion_from_euler,
)
from common.wire.messages import AttitudeEstimate, PoseEstimate, YawEstimate
from services.ros2 import convert

angles = st.floats(-np.pi, np.pi, allow_nan=False)
stamps = st.floats(0.0, 4e9, allow_nan=False)


def wxyz(q_xyzw: tuple[float, float, float, float]) -> np.ndarray:
    return np.array([q_xyzw[3], *q_xyzw[:3]])


@given(stamps)
def test_a_ros_stamp_is_the_same_instant_to_the_nanosecond(stamp_s: float) -> None:
    sec, nanosec = convert.ros_stamp(stamp_s)
    assert 0 <= nanosec < 1_000_000_000
    assert abs(sec + nanosec * 1e-9 - stamp_s) <= 1e-9 + abs(stamp_s) * 1e-15


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
def test_a_stamp_that_is_no_ros_time_is_refused(bad: float) -> None:
    with pytest.raises(InputError):
        convert.ros_stamp(bad)


@given(angles, angles, angles)
def test_quaternions_go_out_in_ros_order_as_the_same_rotation(roll: float, pitch: float, yaw: float) -> None:
    q = quaternion_from_euler(roll, pitch, yaw)
    assert np.allclose(matrix_from_quaternion(wxyz(convert.xyzw(q))), matrix_from_quaternion(q))


@given(angles, st.floats(0.0, 1.0))
def test_the_yaw_is_a_rotation_about_z_with_only_the_yaw_variance_known(yaw: float, variance: float) -> None:
    estimate = YawEstimate(
        uav="uav3", seq=4, stamp_s=12.5, delta_yaw_rad=0.0, yaw_rad=yaw, inlier_count=9, patch_count=12,
        confidence=1.0, low_confidence=False, method="test", yaw_variance_rad2=variance,
    )  # fmt: skip
    o = convert.yaw_orientation(estimate)
    assert o.frame_id == "uav3/yaw_origin" and o.stamp == (12, 500_000_000)
    x, y, z, w = o.q_xyzw
    assert x == y == 0.0
    assert np.isclose(np.angle(np.exp(1j * (2 * np.arctan2(z, w) - yaw))), 0.0, atol=1e-12)
    cov = np.array(o.covariance).reshape(3, 3)
    assert cov[2, 2] == variance and cov[0, 0] == cov[1, 1] == convert.UNKNOWN_VARIANCE_RAD2
    assert np.count_nonzero(cov - np.diag(np.diag(cov))) == 0


@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4), st.lists(st.floats(-1, 1), min_size=9, max_size=9))
def test_the_attitude_keeps_its_rotation_and_its_covariance_row_major(q: list[float], a: list[float]) -> None:
    if np.linalg.norm(q) < 1e-3:
        q = [1.0, 0.0, 0.0, 0.0]
    m = np.array(a).reshape(3, 3)
    covariance = m @ m.T  # any symmetric PSD matrix, not only diagonal ones
    estimate = AttitudeEstimate(
        uav="uav0", seq=0, stamp_s=1.0, q_world_body=normalize_quaternion(q), covariance=covariance
    )
    o = convert.attitude_orientation(estimate)
    assert o.frame_id == "uav0/world"
    assert np.array_equal(np.array(o.covariance).reshape(3, 3), covariance)
    assert np.allclose(matrix_from_quaternion(wxyz(o.q_xyzw)), matrix_from_quaternion(estimate.q_world_body))


@pytest.mark.parametrize(("source", "frame"), [("vo", "uav0/world"), ("pf", "uav0/map")])
def test_a_pose_keeps_its_6x6_covariance_in_the_ros_order(source: str, frame: str) -> None:
    covariance = np.arange(36, dtype=np.float64).reshape(6, 6)
    covariance = covariance + covariance.T  # [x y z | rot x, rot y, rot z], both in capataz and in ROS
    estimate = PoseEstimate(
        uav="uav0", seq=1, stamp_s=3.25, p_world_body_m=np.array([1.0, -2.0, 3.5]),
        q_world_body=np.array([0.0, 1.0, 0.0, 0.0]), covariance=covariance, source=source,
    )  # fmt: skip
    p = convert.pose_of(estimate, source)
    assert p.frame_id == frame and p.stamp == (3, 250_000_000)
    assert p.position_m == (1.0, -2.0, 3.5) and p.q_xyzw == (1.0, 0.0, 0.0, 0.0)
    assert np.array_equal(np.array(p.covariance).reshape(6, 6), covariance)
    assert p.covariance[3 * 6 + 3] == covariance[3, 3]  # rot x variance at ROS index 21


def test_the_mount_is_the_projects_downward_camera() -> None:
    mount = convert.camera_mount("uav1")
    assert (mount.frame_id, mount.child_frame_id) == ("uav1/base_link", "uav1/camera_optical_frame")
    assert mount.translation_m == (0.0, 0.0, 0.0)
    assert np.allclose(matrix_from_quaternion(wxyz(mount.q_xyzw)), R_BODY_CAMERA_DOWN, atol=1e-12)


# ----------------------------------------------------------------------------------------------- in
def header(stamp_s: float) -> Any:
    ns = round(stamp_s * 1e9)
    return Ns(stamp=Ns(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), frame_id="cam")


def image(encoding: str, pixels: np.ndarray, step: int | None = None, stamp_s: float = 1.0) -> Any:
    h, w = pixels.shape[:2]
    data = array.array("B", np.ascontiguousarray(pixels).tobytes())  # what rclpy gives for uint8[]
    row = len(data) // h
    return Ns(header=header(stamp_s), height=h, width=w, encoding=encoding, is_bigendian=0,
              step=row if step is None else step, data=data)  # fmt: skip


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "rgb8", "bgr8"])
def test_each_supported_encoding_becomes_an_8_bit_grey_frame(encoding: str) -> None:
    rng = np.random.default_rng(0)
    grey = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    pixels = {
        "mono8": grey,
        "mono16": grey.astype("<u2") << 8,
        "rgb8": np.repeat(grey[:, :, None], 3, axis=2),
        "bgr8": np.repeat(grey[:, :, None], 3, axis=2),
    }[encoding]
    frame = convert.frame_of("uav0", 7, image(encoding, pixels), False, "/uav0/camera/image_raw")
    assert frame.seq == 7 and frame.stamp_s == 1.0 and (frame.width, frame.height) == (8, 6)
    assert np.array_equal(frame.pixels, grey)


def test_a_padded_step_is_read_row_by_row() -> None:
    grey = np.arange(24, dtype=np.uint8).reshape(4, 6)
    padded = np.zeros((4, 8), dtype=np.uint8)
    padded[:, :6] = grey
    msg = image("mono8", padded, step=8)
    msg.width = 6
    assert np.array_equal(convert.frame_of("uav0", 0, msg, False, "t").pixels, grey)


@pytest.mark.parametrize(
    ("msg", "fragment"),
    [
        (image("yuv422", np.zeros((4, 4), np.uint8)), "not supported"),
        (image("mono8", np.zeros((4, 4), np.uint8), step=3), "does not fit"),
        (image("mono8", np.zeros((4, 4), np.uint8), step=8), "does not fit"),
    ],
    ids=["unknown-encoding", "step-too-short", "step-past-the-data"],
)
def test_an_image_that_cannot_be_a_frame_is_refused_in_one_line(msg: Any, fragment: str) -> None:
    with pytest.raises(InputError, match=fragment) as info:
        convert.frame_of("uav0", 0, msg, False, "/uav0/camera/image_raw")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("extension", [".png", ".jpg"])
def test_a_compressed_image_is_decoded_to_grey(extension: str) -> None:
    grey = np.tile(np.arange(0, 240, 15, dtype=np.uint8), (12, 1))
    ok, encoded = cv2.imencode(extension, grey)
    assert ok
    msg = Ns(header=header(4.0), format=extension[1:], data=array.array("B", encoded.tobytes()))
    frame = convert.frame_of("uav0", 1, msg, True, "/uav0/camera/image_raw/compressed")
    assert frame.stamp_s == 4.0 and frame.pixels.shape == grey.shape
    tolerance = 0 if extension == ".png" else 8  # lossless / lossy
    assert np.abs(frame.pixels.astype(int) - grey).max() <= tolerance


def test_a_compressed_image_that_does_not_decode_is_refused() -> None:
    msg = Ns(header=header(1.0), format="jpeg", data=array.array("B", b"not a jpeg"))
    with pytest.raises(InputError, match="cannot be decoded"):
        convert.frame_of("uav0", 0, msg, True, "/uav0/camera/image_raw/compressed")


def imu(gyro: tuple[float, float, float], accel: tuple[float, float, float] = (0.0, 0.0, 9.81)) -> Any:
    v = lambda x: Ns(x=x[0], y=x[1], z=x[2])  # noqa: E731
    return Ns(header=header(2.0), angular_velocity=v(gyro), linear_acceleration=v(accel))


def test_an_imu_message_becomes_a_body_frame_sample() -> None:
    sample = convert.imu_of("uav0", 3, imu((0.1, -0.2, 0.3)), "/uav0/imu")
    assert sample.stamp_s == 2.0 and sample.seq == 3
    assert np.array_equal(sample.gyro_rad_s, [0.1, -0.2, 0.3]) and np.array_equal(
        sample.accel_m_s2, [0, 0, 9.81]
    )


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_non_finite_imu_message_is_refused(bad: float) -> None:
    with pytest.raises(InputError, match="NaN or inf"):
        convert.imu_of("uav0", 0, imu((0.0, bad, 0.0)), "/uav0/imu")


@pytest.mark.parametrize("value", [float("nan"), 0.01, 60.0, -1.0])
def test_a_range_outside_its_limits_or_not_finite_is_refused(value: float) -> None:
    msg = Ns(header=header(1.0), range=value, min_range=0.05, max_range=50.0)
    with pytest.raises(InputError, match="outside"):
        convert.range_of("uav0", 0, msg, "/uav0/range")
    msg.range = 1.5
    assert convert.range_of("uav0", 0, msg, "/uav0/range").range_m == 1.5


def test_camera_info_becomes_the_projects_camera_model() -> None:
    msg = Ns(width=752, height=480, distortion_model="plumb_bob", d=[0.0] * 5,
             k=[376.0, 0.0, 375.5, 0.0, 376.0, 239.5, 0.0, 0.0, 1.0])  # fmt: skip
    camera = convert.camera_of(msg, "/uav0/camera/camera_info")
    assert (camera.width, camera.height, camera.fx, camera.cy) == (752, 480, 376.0, 239.5)
    msg.k = [0.0] * 9
    with pytest.raises(InputError):
        convert.camera_of(msg, "/uav0/camera/camera_info")
