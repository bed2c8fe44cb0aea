"""capataz messages <-> ROS 2 message fields, as plain values (no rclpy, no zenoh: testable without ROS).

Out (estimates -> ROS), per UAV ``u`` (frame ids prefixed with the UAV, so several UAVs share one tf tree;
each pose is the pose of ``u/base_link``):

| capataz key        | ROS message                                 | header.frame_id  | what               |
| ------------------ | ------------------------------------------- | ---------------- | ------------------ |
| ``uav/u/yaw``      | ``sensor_msgs/Imu`` (orientation only)      | ``u/yaw_origin`` | yaw about z        |
| ``uav/u/attitude`` | ``sensor_msgs/Imu`` (orientation only)      | ``u/world``      | q_world_body       |
| ``uav/u/pose/vo``  | ``geometry_msgs/PoseWithCovarianceStamped`` | ``u/world``      | body pose (VO)     |
| ``uav/u/pose/pf``  | ``geometry_msgs/PoseWithCovarianceStamped`` | ``u/map``        | body pose (map)    |
| (static) mount     | ``geometry_msgs/TransformStamped``          | ``u/base_link``  | camera (below)     |

The mount's child frame is ``u/camera_optical_frame`` (OpenCV axes: x right, y down, z along the axis).

Covariances are the ones the capataz messages carry, laid out as ROS wants them (row-major): the attitude's
3x3 covariance of world-frame error angles is ``orientation_covariance`` (ROS: rotation about the fixed
x, y, z axes); the pose's 6x6 ``[position, error angles]`` is ``PoseWithCovariance.covariance`` unchanged
(same order). The yaw cluster measures yaw alone: its ``orientation_covariance`` is
``diag(UNKNOWN_VARIANCE_RAD2, UNKNOWN_VARIANCE_RAD2, yaw_variance_rad2)`` (roll and pitch not estimated).
``sensor_msgs/Imu`` fields not estimated carry ``-1`` in element 0 of their covariance (the message's own
convention for "no estimate"). Stamps are the sensor stamps (the frame's ``stamp_s``), never the bridge's
clock. Quaternions: capataz is ``[w, x, y, z]``, ROS is ``x, y, z, w``.

In (ROS sensors -> capataz streams): ``sensor_msgs/Image`` (mono8, mono16, rgb8, bgr8) and
``CompressedImage`` go through the bag reader's conversion (:func:`common.datasets.rosbag.image_of`: same
encodings, same step check), ``CameraInfo`` through :func:`common.datasets.rosbag.camera_info_of`;
``Imu`` (body frame, FLU, REP 103's ``base_link``) and ``Range`` (along body -z) become ``ImuSample`` and
``RangeSample`` whose pydantic validation refuses NaN and infinities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.datasets.rosbag import COMPRESSED, camera_info_of, image_of, stamp_of
from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, quaternion_from_euler, quaternion_from_matrix
from common.types import FloatArray
from common.wire.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, RangeSample, YawEstimate

#: variance given to what an estimate does not estimate (roll and pitch of the yaw): rad^2, "unknown"
UNKNOWN_VARIANCE_RAD2 = 1e6
#: element 0 of an ``Imu`` covariance that is not provided (``sensor_msgs/Imu``'s convention)
NOT_PROVIDED = (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
#: the camera mount the project flies today (paper A/C's downward camera): ``R_body_camera``
MOUNT_R_BODY_CAMERA: FloatArray = R_BODY_CAMERA_DOWN


def ros_stamp(stamp_s: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of a stamp in seconds (``builtin_interfaces/Time``; nanoseconds rounded)."""
    if not math.isfinite(stamp_s) or stamp_s < 0.0:
        raise InputError(f"stamp {stamp_s} cannot be a ROS time (finite, >= 0)")
    total_ns = round(stamp_s * 1e9)
    return total_ns // 1_000_000_000, total_ns % 1_000_000_000


def xyzw(q_wxyz: Any) -> tuple[float, float, float, float]:
    """A capataz quaternion ``[w, x, y, z]`` in ROS order ``(x, y, z, w)``."""
    w, x, y, z = (float(v) for v in np.asarray(q_wxyz, dtype=np.float64).reshape(4))
    return x, y, z, w


#: capataz frame -> ROS frame (REP 103/105 names: the body is ``base_link``, the camera an optical frame)
ROS_FRAMES = {"body": "base_link", "camera": "camera_optical_frame"}


def frame_name(uav: str, frame: str) -> str:
    """The ROS frame id of a capataz frame of ``uav``: ``uav0/world``, ``uav0/base_link``, ..."""
    return f"{uav}/{ROS_FRAMES.get(frame, frame)}"


@dataclass(frozen=True)
class Orientation:
    """What a ``sensor_msgs/Imu`` carries of an orientation estimate."""

    uav: str
    stamp: tuple[int, int]
    frame_id: str
    q_xyzw: tuple[float, float, float, float]
    covariance: tuple[float, ...]  # 9, row-major


@dataclass(frozen=True)
class Pose:
    """What a ``geometry_msgs/PoseWithCovarianceStamped`` carries."""

    uav: str
    stamp: tuple[int, int]
    frame_id: str
    position_m: tuple[float, float, float]
    q_xyzw: tuple[float, float, float, float]
    covariance: tuple[float, ...]  # 36, row-major


@dataclass(frozen=True)
class Mount:
    """A static transform ``parent -> child`` (``geometry_msgs/TransformStamped``)."""

    frame_id: str
    child_frame_id: str
    translation_m: tuple[float, float, float]
    q_xyzw: tuple[float, float, float, float]


def _flat(matrix: np.ndarray, n: int) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(matrix, dtype=np.float64).reshape(n * n))


def yaw_orientation(estimate: YawEstimate) -> Orientation:
    """The yaw as an orientation about z of the stream's first frame (roll, pitch unknown)."""
    q = quaternion_from_euler(0.0, 0.0, estimate.yaw_rad)
    cov = np.diag([UNKNOWN_VARIANCE_RAD2, UNKNOWN_VARIANCE_RAD2, estimate.yaw_variance_rad2])
    return Orientation(
        estimate.uav,
        ros_stamp(estimate.stamp_s),
        frame_name(estimate.uav, "yaw_origin"),
        xyzw(q),
        _flat(cov, 3),
    )


def attitude_orientation(estimate: AttitudeEstimate) -> Orientation:
    return Orientation(
        estimate.uav,
        ros_stamp(estimate.stamp_s),
        frame_name(estimate.uav, estimate.frame_id),
        xyzw(estimate.q_world_body),
        _flat(estimate.covariance, 3),
    )


#: the parent frame of each pose source (the localizer's world is its map, not the VO's origin)
POSE_FRAMES = {"vo": "world", "pf": "map"}


def pose_of(estimate: PoseEstimate, source: str) -> Pose:
    """A pose of ``source`` (``vo``/``pf``): position, orientation, the 6x6 covariance as is."""
    p = np.asarray(estimate.p_world_body_m, dtype=np.float64)
    return Pose(
        estimate.uav,
        ros_stamp(estimate.stamp_s),
        frame_name(estimate.uav, POSE_FRAMES.get(source, estimate.frame_id)),
        (float(p[0]), float(p[1]), float(p[2])),
        xyzw(estimate.q_world_body),
        _flat(estimate.covariance, 6),
    )


def camera_mount(uav: str, R_body_camera: FloatArray = MOUNT_R_BODY_CAMERA) -> Mount:
    """The camera on the body as a static transform ``u/base_link -> u/camera_optical_frame`` (at the body
    origin: the project's simulation puts the camera there)."""
    return Mount(
        frame_name(uav, "body"),
        frame_name(uav, "camera"),
        (0.0, 0.0, 0.0),
        xyzw(quaternion_from_matrix(R_body_camera)),
    )


# ----------------------------------------------------------------------------------------------- in
def frame_of(uav: str, seq: int, msg: Any, compressed: bool, topic: str) -> Frame:
    """A ROS ``Image`` / ``CompressedImage`` as a capataz frame (8-bit grey); InputError when it cannot be."""
    pixels = image_of(msg, COMPRESSED if compressed else "sensor_msgs/msg/Image", topic)
    try:
        return Frame(
            uav=uav,
            seq=seq,
            stamp_s=stamp_of(msg),
            width=pixels.shape[1],
            height=pixels.shape[0],
            pixels=pixels,
        )
    except ValueError as exc:
        raise InputError(f"{topic}: {_first_error(exc)}") from None


def imu_of(uav: str, seq: int, msg: Any, topic: str) -> ImuSample:
    """A ROS ``Imu`` (body frame) as an IMU sample; NaN or infinite values are refused."""
    g, a = msg.angular_velocity, msg.linear_acceleration
    try:
        return ImuSample(
            uav=uav,
            seq=seq,
            stamp_s=stamp_of(msg),
            gyro_rad_s=np.array([g.x, g.y, g.z], dtype=np.float64),
            accel_m_s2=np.array([a.x, a.y, a.z], dtype=np.float64),
        )
    except ValueError as exc:
        raise InputError(f"{topic}: {_first_error(exc)}") from None


def range_of(uav: str, seq: int, msg: Any, topic: str) -> RangeSample:
    """A ROS ``Range`` as a range sample; outside ``[min_range, max_range]`` or not finite is refused."""
    value = float(msg.range)
    if not (math.isfinite(value) and value > 0.0 and msg.min_range <= value <= msg.max_range):
        raise InputError(f"{topic}: range {value} outside [{msg.min_range}, {msg.max_range}]")
    try:
        return RangeSample(uav=uav, seq=seq, stamp_s=stamp_of(msg), range_m=value)
    except ValueError as exc:
        raise InputError(f"{topic}: {_first_error(exc)}") from None


def camera_of(msg: Any, topic: str) -> Any:
    """A ROS ``CameraInfo`` as the project's camera model (InputError when it is not a usable one)."""
    return camera_info_of(msg, topic)


def _first_error(exc: ValueError) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        first = errors()[0]
        where = ".".join(str(p) for p in first.get("loc", ()))
        text = str(first.get("msg", exc)).removeprefix("Value error, ")
        return f"{where}: {text}" if where else text
    return str(exc).splitlines()[0]
