"""Write a measurement stream as a ROS bag with ``rosbags``' writers (ROS 2: MCAP or sqlite3; ROS 1).

How capataz exports a simulated flight for ROS tools (and how its tests make bags): frames as
``sensor_msgs/Image`` (or ``CompressedImage`` PNG), IMU, range and one ``CameraInfo``, each message's
log time equal to its ``header.stamp``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from common.camera import CameraModel, DistortionModel
from common.datasets.rosbag import COMPRESSED, IMAGE, IMU, INFO, RANGE, BagError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement

#: topics of a written bag
TOPICS = {
    "image": "/camera/image_raw",
    "imu": "/imu",
    "range": "/range",
    "camera_info": "/camera/camera_info",
}


def write_bag(
    path: Path,
    measurements: Iterable[Measurement],
    camera_info: CameraModel | None = None,
    kind: Literal["ros2-mcap", "ros2-sqlite3", "ros1"] = "ros2-mcap",
    encoding: Literal["mono8", "bgr8", "rgb8", "mono16", "png"] = "mono8",
    range_limits_m: tuple[float, float] = (0.01, 100.0),
) -> Path:
    """Write ``measurements`` (stamp order) to a new bag at ``path`` (a folder for ROS 2, a ``.bag`` file
    for ROS 1). ``encoding`` is how frames are stored (``png``: CompressedImage)."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = ts.types
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr

    def header(stamp_s: float, frame_id: str) -> Any:
        ns = round(stamp_s * 1e9)
        if ns < 0:
            raise BagError(f"bag stamps must be >= 0, got {stamp_s} s")
        time = T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=time, frame_id=frame_id)
        return T["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    vec = T["geometry_msgs/msg/Vector3"]
    image_type = COMPRESSED if encoding == "png" else IMAGE
    writer = _open_writer(Path(path), kind)
    with writer:
        conn = {
            "image": writer.add_connection(TOPICS["image"], image_type, typestore=ts),
            "imu": writer.add_connection(TOPICS["imu"], IMU, typestore=ts),
            "range": writer.add_connection(TOPICS["range"], RANGE, typestore=ts),
        }
        if camera_info is not None:
            conn["camera_info"] = writer.add_connection(TOPICS["camera_info"], INFO, typestore=ts)
        info_written = False
        for m in measurements:
            ns = round(m.stamp_s * 1e9)
            if isinstance(m, FrameMeasurement):
                if camera_info is not None and not info_written:
                    msg = _camera_info_msg(T, camera_info, header(m.stamp_s, "camera"), ros1)
                    writer.write(conn["camera_info"], ns, serialize(msg, INFO))
                    info_written = True
                msg = _image_msg(T, m.image, encoding, header(m.stamp_s, "camera"))
                writer.write(conn["image"], ns, serialize(msg, image_type))
            elif isinstance(m, ImuMeasurement):
                g, a = m.gyro_rad_s, m.accel_m_s2
                msg = T[IMU](
                    header=header(m.stamp_s, "body"),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.array([-1.0] + [0.0] * 8),  # -1: no orientation
                    angular_velocity=vec(x=float(g[0]), y=float(g[1]), z=float(g[2])),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=vec(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                    linear_acceleration_covariance=np.zeros(9),
                )
                writer.write(conn["imu"], ns, serialize(msg, IMU))
            elif isinstance(m, RangeMeasurement):
                msg = T[RANGE](
                    header=header(m.stamp_s, "rangefinder"),
                    radiation_type=1,
                    field_of_view=0.05,
                    min_range=range_limits_m[0],
                    max_range=range_limits_m[1],
                    range=m.range_m,
                )
                writer.write(conn["range"], ns, serialize(msg, RANGE))
    return Path(path)


def _open_writer(path: Path, kind: str) -> Any:
    if kind == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        return Writer1(path)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    plugin = StoragePlugin.MCAP if kind == "ros2-mcap" else StoragePlugin.SQLITE3
    return Writer2(path, version=9, storage_plugin=plugin)


def _image_msg(T: Any, image: np.ndarray, encoding: str, header: Any) -> Any:
    h, w = image.shape
    if encoding == "png":
        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise BagError("frame cannot be encoded as PNG")
        return T[COMPRESSED](header=header, format="png", data=png.reshape(-1))
    if encoding == "mono16":
        data = (image.astype("<u2") << 8).view(np.uint8).reshape(-1)
        step = 2 * w
    elif encoding in ("bgr8", "rgb8"):
        data = np.repeat(image[:, :, None], 3, axis=2).reshape(-1)
        step = 3 * w
    else:
        data, step = image.reshape(-1), w
    return T[IMAGE](
        header=header,
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=np.ascontiguousarray(data, dtype=np.uint8),
    )


#: ROS's names of the distortion models
ROS_DISTORTION = {
    DistortionModel.NONE: "plumb_bob",
    DistortionModel.RADTAN: "plumb_bob",
    DistortionModel.FISHEYE: "equidistant",
}


def _camera_info_msg(T: Any, camera: CameraModel, header: Any, ros1: bool) -> Any:
    k = camera.K.reshape(-1)
    p = np.array([camera.fx, 0.0, camera.cx, 0.0, 0.0, camera.fy, camera.cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    d = np.array(camera.distortion.coeffs or (0.0,) * 5, dtype=np.float64)
    matrices = {"D": d, "K": k, "R": np.eye(3).reshape(-1), "P": p}
    if not ros1:
        matrices = {name.lower(): value for name, value in matrices.items()}
    return T[INFO](
        header=header,
        height=camera.height,
        width=camera.width,
        distortion_model=ROS_DISTORTION[camera.distortion.model],
        binning_x=0,
        binning_y=0,
        roi=roi,
        **matrices,
    )
