"""The bridge service: a ROS 2 node (rclpy, Fast DDS on loopback) wired to the Zenoh keys of its UAVs.

Out: each estimate a Zenoh subscriber receives is converted (:mod:`services.ros2.convert`) and published
on its ROS topic (sensor-data QoS: best effort, keep last 5); the camera mount is published once, reliable
and transient local (late joiners get it), as a ``geometry_msgs/TransformStamped`` on
``/{uav}/capataz/camera_mount`` and on ``/tf_static`` as a ``tf2_msgs/TFMessage`` (PyPI has no tf2_msgs
wheel: :mod:`services.ros2.tf2_msgs_build` builds it into the environment; without it, one warning line).
In: ROS sensor messages pass the stream gate (:mod:`services.ros2.inputs`) and the wire messages'
validation, then go out on the UAV's capataz keys; a refused one is counted under its reason and logged in
one line (the first 20, then every 100th).
"""

from __future__ import annotations

import logging
import time
from functools import partial
from pathlib import Path
from typing import Any

import zenoh

from common.datasets.calibration import opencv_yaml_text
from common.errors import InputError
from common.members import Role
from common.streams import FrameKey
from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import AttitudeEstimate, Frame, PoseEstimate, YawEstimate
from common.wire.schema import WireModel
from services.ros2 import convert
from services.ros2.dds import DEFAULT_PROFILE_PATH, apply_environment, dds_environment, profile_for
from services.ros2.inputs import SensorGates
from services.ros2.settings import IN_TOPICS, Ros2Settings, in_topic, out_topic
from services.runtime.service import ConfiguredService

logger = logging.getLogger(__name__)

#: how long one executor turn waits for ROS callbacks (the stop flag is checked between turns)
SPIN_S = 0.05
#: history of each input subscription (messages): about 1 s of a 400 Hz IMU, 0.5 s of a 20 fps camera
INPUT_DEPTH = {"image": 10, "compressed": 10, "camera_info": 5, "imu": 400, "range": 100}


def _tf2_message() -> Any:
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class Ros2Bridge(ConfiguredService[Ros2Settings]):
    role = Role.BRIDGE

    def setup(self) -> None:
        self.profile = self.settings.dds_profile or DEFAULT_PROFILE_PATH
        self.gates = SensorGates()
        self._cameras: dict[str, Any] = {}
        self._zpub: dict[tuple[str, str], Any] = {}
        self.context: Any = None
        self.ros_node: Any = None
        self._static: list[Any] = []

    # -- ROS side ---------------------------------------------------------------------------------------
    def _open_ros(self) -> None:
        self.profile = profile_for(self.settings.dds_profile)
        apply_environment(dds_environment(self.profile, self.settings.domain_id))
        import rclpy
        from rclpy.context import Context
        from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy, qos_profile_sensor_data
        from rclpy.signals import SignalHandlerOptions

        self.context = Context()
        rclpy.init(
            context=self.context,
            domain_id=self.settings.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
        )
        name = "".join(c if c.isalnum() else "_" for c in f"capataz_bridge_{self.node}_{self.index}")
        self.ros_node = rclpy.create_node(name, context=self.context)
        self.sensor_qos = qos_profile_sensor_data
        # inputs: best effort like the sensor-data profile, with deeper histories: 5 samples (the profile's)
        # and then 50 lost IMU samples whenever this one executor thread stalled on a shared host (bench ros2)
        self.input_qos = {
            stream: QoSProfile(depth=depth, reliability=qos_profile_sensor_data.reliability)
            for stream, depth in INPUT_DEPTH.items()
        }
        self.static_qos = QoSProfile(
            depth=1,
            reliability=QoSReliabilityPolicy.RELIABLE,
            durability=QoSDurabilityPolicy.TRANSIENT_LOCAL,
        )

    def _spin(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        context = self.context
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(self.ros_node)
        try:
            while not self.stop_event.is_set() and context.ok():
                executor.spin_once(timeout_sec=SPIN_S)
        finally:
            executor.remove_node(self.ros_node)
            executor.shutdown()

    # -- lifecycle --------------------------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        self._open_ros()
        for uav in self.settings.uavs:
            self._wire_out(session, uav)
        for uav in self.settings.input_uavs:
            self._wire_in(session, uav)
        self.spawn(self._spin, "ros")
        logger.info(
            "%s: ROS 2 domain %d, DDS profile %s; out %s, in %s",
            self.name,
            self.settings.domain_id,
            self.profile,
            ",".join(self.settings.uavs) or "none",
            ",".join(self.settings.input_uavs) or "none",
        )

    def stop(self) -> None:
        super().stop()
        context, self.context = self.context, None
        if context is not None:
            for thread in self._threads:
                thread.join(1.0)
            try:
                if self.ros_node is not None:
                    self.ros_node.destroy_node()
                context.try_shutdown()
            except Exception as exc:  # shutting down: counted, never a traceback
                self.count_error("ros_shutdown", "ROS 2 shutdown", exc)

    # -- out: capataz estimates -> ROS 2 ---------------------------------------------------------------
    def _wire_out(self, session: zenoh.Session, uav: str) -> None:
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from sensor_msgs.msg import Imu

        node, qos = self.ros_node, self.sensor_qos
        outs: dict[str, tuple[str, type[WireModel], Any]] = {
            "yaw": (keys.yaw_key(uav), YawEstimate, node.create_publisher(Imu, out_topic(uav, "yaw"), qos)),
            "attitude": (
                keys.attitude_key(uav),
                AttitudeEstimate,
                node.create_publisher(Imu, out_topic(uav, "attitude"), qos),
            ),
            "pose/vo": (
                keys.pose_vo_key(uav),
                PoseEstimate,
                node.create_publisher(PoseWithCovarianceStamped, out_topic(uav, "pose/vo"), qos),
            ),
            "pose/pf": (
                keys.pose_pf_key(uav),
                PoseEstimate,
                node.create_publisher(PoseWithCovarianceStamped, out_topic(uav, "pose/pf"), qos),
            ),
        }
        for name, (key, kind, publisher) in outs.items():
            callback = partial(self._on_estimate, name, kind, publisher)
            self.subscriptions.append(session.declare_subscriber(key, callback))
        self._publish_mount(uav)

    def _publish_mount(self, uav: str) -> None:
        """The camera mount, once, transient local: on its own topic and, with tf2_msgs, on /tf_static."""
        from geometry_msgs.msg import TransformStamped

        node = self.ros_node
        mount = convert.camera_mount(uav)
        transform = TransformStamped()
        transform.header.stamp = self.ros_node.get_clock().now().to_msg()
        transform.header.frame_id = mount.frame_id
        transform.child_frame_id = mount.child_frame_id
        t, q = transform.transform.translation, transform.transform.rotation
        t.x, t.y, t.z = mount.translation_m
        q.x, q.y, q.z, q.w = mount.q_xyzw
        static_pub = node.create_publisher(TransformStamped, out_topic(uav, "camera_mount"), self.static_qos)
        static_pub.publish(transform)
        self._static.append(static_pub)
        tf_message = _tf2_message()
        if tf_message is None:
            logger.warning(
                "no /tf_static for %s: tf2_msgs is not importable (capataz ros2 --build-tf2-msgs builds it)",
                uav,
            )
        else:
            tf_pub = node.create_publisher(tf_message, "/tf_static", self.static_qos)
            tf_pub.publish(tf_message(transforms=[transform]))
            self._static.append(tf_pub)

    def _on_estimate(self, name: str, kind: type[WireModel], publisher: Any, sample: zenoh.Sample) -> None:
        received_s = time.perf_counter()
        message = self.decode_sample(sample, kind)
        if message is None:
            return
        try:
            ros = self._ros_message(name, message)
        except InputError as exc:
            self.count_error("unconvertible", f"{name} not bridged", exc)
            return
        try:
            publisher.publish(ros)
        except Exception as exc:  # the context is shutting down under a zenoh callback
            if not self.stop_event.is_set():
                self.count_error("ros_publish_failures", f"cannot publish {name}", exc)
            return
        self.counters.inc(f"out_{name.replace('/', '_')}")
        self.counters.time_ms("out", (time.perf_counter() - received_s) * 1e3)

    def _ros_message(self, name: str, message: Any) -> Any:
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from sensor_msgs.msg import Imu

        if name in ("yaw", "attitude"):
            o = convert.yaw_orientation(message) if name == "yaw" else convert.attitude_orientation(message)
            imu = Imu()
            imu.header.stamp.sec, imu.header.stamp.nanosec = o.stamp
            imu.header.frame_id = o.frame_id
            q = imu.orientation
            q.x, q.y, q.z, q.w = o.q_xyzw
            imu.orientation_covariance = list(o.covariance)
            imu.angular_velocity_covariance = list(convert.NOT_PROVIDED)
            imu.linear_acceleration_covariance = list(convert.NOT_PROVIDED)
            return imu
        p = convert.pose_of(message, name.split("/")[1])
        pose = PoseWithCovarianceStamped()
        pose.header.stamp.sec, pose.header.stamp.nanosec = p.stamp
        pose.header.frame_id = p.frame_id
        position, q = pose.pose.pose.position, pose.pose.pose.orientation
        position.x, position.y, position.z = p.position_m
        q.x, q.y, q.z, q.w = p.q_xyzw
        pose.pose.covariance = list(p.covariance)
        return pose

    # -- in: ROS 2 sensors -> capataz streams ----------------------------------------------------------
    def declare_inputs(self, session: zenoh.Session, uav: str) -> None:
        """The capataz keys ``uav``'s ROS sensors go out on."""
        self._zpub[uav, "camera"] = session.declare_publisher(keys.camera_key(uav))
        self._zpub[uav, "imu"] = session.declare_publisher(keys.imu_key(uav))
        self._zpub[uav, "range"] = session.declare_publisher(keys.range_key(uav))

    def _wire_in(self, session: zenoh.Session, uav: str) -> None:
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, Range

        self.declare_inputs(session, uav)
        kinds = {"image": Image, "compressed": CompressedImage, "camera_info": CameraInfo}
        kinds |= {"imu": Imu, "range": Range}
        for stream, kind in kinds.items():
            topic = in_topic(uav, IN_TOPICS[stream])
            callback = partial(self.on_sensor, uav, stream, topic)
            self.ros_node.create_subscription(kind, topic, callback, self.input_qos[stream])

    def on_sensor(self, uav: str, stream: str, topic: str, msg: Any) -> None:
        """One ROS message of ``uav``'s ``stream``: converted, gated, forwarded, or refused and counted."""
        received_s = time.perf_counter()
        self.counters.inc(f"in_{stream}")
        try:
            if stream == "camera_info":
                self._on_camera_info(uav, msg, topic)
                return
            kind = "camera" if stream in ("image", "compressed") else stream
            seq = self.gates.next_seq(uav, kind)
            if kind == "camera":
                message: Any = convert.frame_of(uav, seq, msg, stream == "compressed", topic)
                self._check_camera(uav, message, topic)
                key: FrameKey | None = FrameKey(message.width, message.height, "mono8")
            else:
                convert_sensor = convert.imu_of if kind == "imu" else convert.range_of
                message, key = convert_sensor(uav, seq, msg, topic), None
        except InputError as exc:
            self.count_error("refused_malformed", f"refused {topic}", exc)
            return
        decision = self.gates.admit(uav, kind, seq, message.stamp_s, key)
        if not decision.admitted:
            self.count_error(f"refused_{decision.reason}", f"refused {topic}", decision.detail)
            return
        self._forward(uav, kind, message)
        self.counters.time_ms("in", (time.perf_counter() - received_s) * 1e3)

    def _forward(self, uav: str, kind: str, message: Any) -> None:
        publisher = self._zpub[uav, kind]
        payload, attachment = encode(message)
        try:
            if isinstance(message, Frame):  # the declared source: masters follow one camera per stream
                source = zenoh.SourceInfo(publisher.id, message.seq)
                publisher.put(payload, attachment=attachment, source_info=source)
            else:
                publisher.put(payload, attachment=attachment)
        except zenoh.ZError as exc:
            if not self.stop_event.is_set():
                self.count_error("zenoh_put_failures", f"cannot publish {kind}", exc)
            return
        self.counters.inc(f"forwarded_{kind}")

    def _on_camera_info(self, uav: str, msg: Any, topic: str) -> None:
        camera = convert.camera_of(msg, topic)
        if self._cameras.get(uav) == camera:
            return
        self._cameras[uav] = camera
        logger.info("%s: %s camera %dx%d fx %.2f fy %.2f", self.name, uav, camera.width, camera.height,
                    camera.fx, camera.fy)  # fmt: skip
        path = self.settings.calibration_out
        if path is not None:
            target = Path(str(path).replace("{uav}", uav))
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(opencv_yaml_text(camera))

    def _check_camera(self, uav: str, frame: Frame, topic: str) -> None:
        camera = self._cameras.get(uav)
        if camera is not None and (camera.width, camera.height) != (frame.width, frame.height):
            size = f"{frame.width}x{frame.height}"
            raise InputError(f"{topic}: {size} image, camera_info says {camera.width}x{camera.height}")
