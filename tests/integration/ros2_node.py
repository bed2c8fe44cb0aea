"""A real ROS 2 node (rclpy, its own process) for the bridge's end-to-end test.

``python -m tests.integration.ros2_node CONFIG.json``: publishes a simulated hover flight's images (mono8),
camera info, IMU and range on ``/{uav}/...`` in stamp order at ``fps`` frames per second, subscribes to the
bridge's estimates (``/{uav}/capataz/...``) and the camera mount (its own topic and ``/tf_static``, a
``tf2_msgs/TFMessage``: the package ``services.ros2.tf2_msgs_build`` built), and, once the file ``done``
names exists (or ``timeout_s`` passed), writes everything it received to ``out`` as JSON, with the UDP
sockets it had open and the publishers of ``/tf_static`` (node, type, type hash). The environment
(domain, Fast DDS profile) is the caller's.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, Imu, Range
from tf2_msgs.msg import TFMessage

from common.estimation.measurements import FrameMeasurement, ImuMeasurement, RangeMeasurement
from common.sim.flight import hover_flight
from common.sim.stream import flight_measurements
from services.ros2.dds import udp_sockets_of

RELIABLE = QoSProfile(depth=50, reliability=QoSReliabilityPolicy.RELIABLE)
STATIC = QoSProfile(
    depth=1, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
)


def stamp(msg: Any, stamp_s: float) -> None:
    ns = round(stamp_s * 1e9)
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000


def publish_bad_input(uav: str, last_s: float, images: Any, imus: Any, ranges: Any) -> None:
    """After the flight: an unknown encoding, a wrong step, a NaN IMU sample, an IMU stamp going back, a NaN
    range (the bridge refuses and counts each; nothing of it reaches capataz)."""
    unknown = Image(height=4, width=4, encoding="yuv422", step=8, data=bytes(32))
    short_step = Image(height=4, width=4, encoding="mono8", step=3, data=bytes(16))
    nan_imu, back_imu = Imu(), Imu()
    nan_imu.angular_velocity.x = float("nan")
    nan_range = Range(min_range=0.05, max_range=50.0, range=float("nan"))
    for msg, stamp_s in (
        (unknown, 1.0),
        (short_step, 1.1),
        (nan_imu, 1.0),
        (back_imu, -0.5),
        (nan_range, 1.0),
    ):
        stamp(msg, last_s + stamp_s)
    images.publish(unknown)
    images.publish(short_step)
    imus.publish(nan_imu)
    imus.publish(back_imu)
    ranges.publish(nan_range)


def main(config_path: str) -> int:
    config = json.loads(Path(config_path).read_text())
    uav, fps, frames = config["uav"], float(config["fps"]), int(config["frames"])
    flight = hover_flight(seed=0, n_frames=frames)
    rclpy.init()
    node = rclpy.create_node("capataz_test_flight")
    names = ("yaw", "attitude", "pose/vo", "pose/pf", "mount", "tf_static")
    received: dict[str, list[Any]] = {name: [] for name in names}

    def orientation(name: str) -> Any:
        def on(msg: Imu) -> None:
            q = msg.orientation
            received[name].append(
                [msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
                 [q.x, q.y, q.z, q.w], list(msg.orientation_covariance)]
            )  # fmt: skip

        return on

    def pose(name: str) -> Any:
        def on(msg: PoseWithCovarianceStamped) -> None:
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            received[name].append(
                [msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
                 [p.x, p.y, p.z], [q.x, q.y, q.z, q.w], list(msg.pose.covariance)]
            )  # fmt: skip

        return on

    def transform(msg: TransformStamped) -> list[Any]:
        t, q = msg.transform.translation, msg.transform.rotation
        return [msg.header.frame_id, msg.child_frame_id, [t.x, t.y, t.z], [q.x, q.y, q.z, q.w]]

    def on_mount(msg: TransformStamped) -> None:
        received["mount"].append(transform(msg))

    def on_tf_static(msg: TFMessage) -> None:
        received["tf_static"].append([transform(t) for t in msg.transforms])

    # best effort like the bridge's publishers, with a history deep enough for the attitude's IMU rate while
    # this one thread also publishes the flight (the sensor-data profile keeps the last 5)
    qos = QoSProfile(depth=2000, reliability=qos_profile_sensor_data.reliability)
    subs = [
        node.create_subscription(Imu, f"/{uav}/capataz/yaw", orientation("yaw"), qos),
        node.create_subscription(Imu, f"/{uav}/capataz/attitude", orientation("attitude"), qos),
        node.create_subscription(PoseWithCovarianceStamped, f"/{uav}/capataz/pose/vo", pose("pose/vo"), qos),
        node.create_subscription(PoseWithCovarianceStamped, f"/{uav}/capataz/pose/pf", pose("pose/pf"), qos),
        node.create_subscription(TransformStamped, f"/{uav}/capataz/camera_mount", on_mount, STATIC),
        node.create_subscription(TFMessage, "/tf_static", on_tf_static, STATIC),
    ]
    images = node.create_publisher(Image, f"/{uav}/camera/image_raw", RELIABLE)
    infos = node.create_publisher(CameraInfo, f"/{uav}/camera/camera_info", RELIABLE)
    imus = node.create_publisher(Imu, f"/{uav}/imu", RELIABLE)
    ranges = node.create_publisher(Range, f"/{uav}/range", RELIABLE)

    deadline = time.monotonic() + float(config["timeout_s"])
    # the bridge reads every sensor topic and publishes every estimate topic before the flight starts
    while time.monotonic() < deadline and not (
        all(p.get_subscription_count() for p in (images, infos, imus, ranges))
        and all(s.get_publisher_count() for s in subs)
    ):
        rclpy.spin_once(node, timeout_sec=0.05)
    Path(config["ready"]).write_text("ready")

    camera = flight.camera
    info = CameraInfo(width=camera.width, height=camera.height, distortion_model="plumb_bob")
    info.k = [camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0]
    info.d = [0.0] * 5
    t0, previous, sent = time.monotonic(), -np.inf, 0
    for m in flight_measurements(flight):  # before each frame, its IMU and range samples
        if isinstance(m, ImuMeasurement):
            imu = Imu()
            stamp(imu, m.stamp_s)
            g, a = m.gyro_rad_s, m.accel_m_s2
            imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = map(float, g)
            imu.linear_acceleration.x, imu.linear_acceleration.y, imu.linear_acceleration.z = map(float, a)
            imus.publish(imu)
        elif isinstance(m, RangeMeasurement):
            r = Range(min_range=0.05, max_range=50.0, range=float(m.range_m))
            stamp(r, m.stamp_s)
            ranges.publish(r)
        elif isinstance(m, FrameMeasurement):
            pixels = m.image
            image = Image(
                height=pixels.shape[0], width=pixels.shape[1], encoding="mono8", step=pixels.shape[1]
            )
            image.data = pixels.tobytes()
            stamp(image, m.stamp_s)
            stamp(info, m.stamp_s)
            infos.publish(info)
            images.publish(image)
            previous, sent = m.stamp_s, sent + 1
            while time.monotonic() < t0 + sent / fps:
                rclpy.spin_once(node, timeout_sec=0.005)
    publish_bad_input(uav, previous, images, imus, ranges)
    done = Path(config["done"])
    while time.monotonic() < deadline and not done.exists():
        rclpy.spin_once(node, timeout_sec=0.05)
    received["udp_sockets"] = [list(s) for s in udp_sockets_of()]
    # the type the bridge's /tf_static publisher announces to the graph (name and RIHS01 type hash)
    received["tf_static_publishers"] = [
        [info.node_name, info.topic_type, str(info.topic_type_hash)]
        for info in node.get_publishers_info_by_topic("/tf_static")
    ]
    Path(config["out"]).write_text(json.dumps(received))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
