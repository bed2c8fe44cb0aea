"""ROS 2 bridge: latency added per message and the rates it sustains, both directions at once.

One router and ``capataz ros2`` (its own process) on 127.0.0.1; this process is both sides: a ROS 2 node
(rclpy, the loopback Fast DDS profile, a random domain) publishes 752x480 mono8 images at ``--fps`` and IMU
samples at ``--imu-hz`` into the bridge, and a Zenoh client publishes every estimate stream (yaw and poses
at ``--fps``, attitude at ``--imu-hz``, as the estimator does) out through it. Each message's stamp is the
wall clock when it was sent, so the receiver's ``time.time() - stamp`` is the time through DDS, the bridge
and Zenoh (one clock, one host). Reported per stream: sent, received, the received rate, and latency
median / p99 over the messages after ``--warmup`` seconds. Needs the ros2 extra.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from common.dispatch import Balance
from common.errors import CapatazError
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, YawEstimate
from common.wire.schema import WireModel
from services.master.service import Topology
from services.ros2 import MISSING_EXTRA, extra_installed
from services.ros2.dds import apply_environment, dds_environment, random_domain_id, write_profile
from services.runtime.transport import open_session, zbytes
from services.tools.up import ClusterSpec, HostSpec, LocalCluster

NAME = "ros2"
UAV = "uav0"
SPEC = ClusterSpec(
    name="ros2",
    topology=Topology.MASTER_WORKER,
    balance=Balance.TIME,
    hosts=(HostSpec(name="h1", workers=1),),
)
WIDTH, HEIGHT = 752, 480


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the run (default 20)")
    parser.add_argument("--fps", type=float, default=20.0, help="camera and yaw/pose rate (default 20)")
    parser.add_argument("--imu-hz", type=float, default=400.0, help="IMU and attitude rate (default 400)")
    parser.add_argument("--warmup", type=float, default=2.0, help="first seconds not counted (default 2)")


class _Arrivals:
    """Latency samples per stream: ``(sent wall time, latency s)``."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.samples: dict[str, list[tuple[float, float]]] = defaultdict(list)
        self.sent: dict[str, list[float]] = defaultdict(list)

    def arrived(self, stream: str, stamp_s: float) -> None:
        now = time.time()
        with self.lock:
            self.samples[stream].append((stamp_s, now - stamp_s))

    def send(self, stream: str, stamp_s: float) -> None:
        with self.lock:
            self.sent[stream].append(stamp_s)


def _paced(stop: threading.Event, hz: float, send: Any) -> None:
    t0, k = time.monotonic(), 0
    while not stop.is_set():
        send(k)
        k += 1
        delay = t0 + k / hz - time.monotonic()
        if delay > 0:
            stop.wait(delay)


def _ros_side(node: Any, arrivals: _Arrivals) -> tuple[dict[str, Any], list[Any]]:
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from rclpy.qos import QoSProfile, qos_profile_sensor_data
    from sensor_msgs.msg import Image, Imu

    def on(stream: str) -> Any:
        def callback(msg: Any) -> None:
            arrivals.arrived(stream, msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)

        return callback

    deep = QoSProfile(depth=1000, reliability=qos_profile_sensor_data.reliability)
    subs = [
        node.create_subscription(Imu, f"/{UAV}/capataz/yaw", on("out yaw"), deep),
        node.create_subscription(Imu, f"/{UAV}/capataz/attitude", on("out attitude"), deep),
        node.create_subscription(
            PoseWithCovarianceStamped, f"/{UAV}/capataz/pose/vo", on("out pose/vo"), deep
        ),
        node.create_subscription(
            PoseWithCovarianceStamped, f"/{UAV}/capataz/pose/pf", on("out pose/pf"), deep
        ),
    ]
    pubs = {
        "in camera": node.create_publisher(Image, f"/{UAV}/camera/image_raw", 10),
        "in imu": node.create_publisher(Imu, f"/{UAV}/imu", 100),
    }
    return pubs, subs


def _estimate(stream: str, k: int, stamp_s: float) -> WireModel:
    if stream == "out yaw":
        return YawEstimate(
            uav=UAV, seq=k, stamp_s=stamp_s, delta_yaw_rad=0.001, yaw_rad=0.001 * k, inlier_count=40,
            patch_count=48, confidence=0.9, low_confidence=False, method="bench", yaw_variance_rad2=1e-6,
        )  # fmt: skip
    if stream == "out attitude":
        q = np.array([1.0, 0.0, 0.0, 0.0])
        return AttitudeEstimate(uav=UAV, seq=k, stamp_s=stamp_s, q_world_body=q, covariance=np.eye(3) * 1e-4)
    return PoseEstimate(
        uav=UAV, seq=k, stamp_s=stamp_s, p_world_body_m=np.array([0.01 * k, 0.0, 1.0]),
        q_world_body=np.array([1.0, 0.0, 0.0, 0.0]), covariance=np.eye(6) * 1e-3, source=stream[-2:],
    )  # fmt: skip


def run(args: argparse.Namespace) -> dict[str, Any]:
    if not extra_installed():
        raise CapatazError(MISSING_EXTRA)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Image, Imu

    out_dir = Path(args.out) if getattr(args, "out", None) else Path("out/bench")
    domain = random_domain_id()
    profile = write_profile(out_dir / "ros2_fastdds.xml")
    apply_environment(dds_environment(profile, domain))
    arrivals = _Arrivals()
    stop = threading.Event()
    with LocalCluster(SPEC, out_dir / "ros2_logs") as cluster:
        cluster.start_router()
        cluster.spawn(
            "bridge/ros2/0",
            ["ros2", *cluster.transport_args(), "--uav", UAV, "--input-uav", UAV,
             "--domain-id", str(domain), "--dds-profile", str(profile)],
        )  # fmt: skip
        cluster.wait_alive({"bridge/ros2/0"})
        rclpy.init(domain_id=domain)
        node = rclpy.create_node("capataz_bench_ros2")
        pubs, subs = _ros_side(node, arrivals)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spinner = threading.Thread(target=lambda: _spin(executor, stop), daemon=True)
        spinner.start()
        with open_session(cluster.observer_transport()) as session:
            zsubs = [
                session.declare_subscriber(keys.camera_key(UAV), _on_zenoh(arrivals, "in camera", Frame)),
                session.declare_subscriber(keys.imu_key(UAV), _on_zenoh(arrivals, "in imu", ImuSample)),
            ]
            zpubs: dict[str, Any] = {
                "out yaw": session.declare_publisher(keys.yaw_key(UAV)),
                "out attitude": session.declare_publisher(keys.attitude_key(UAV)),
                "out pose/vo": session.declare_publisher(keys.pose_vo_key(UAV)),
                "out pose/pf": session.declare_publisher(keys.pose_pf_key(UAV)),
            }
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and not (
                all(p.get_subscription_count() for p in pubs.values())
                and all(s.get_publisher_count() for s in subs)
                and all(p.matching_status.matching for p in zpubs.values())
            ):
                time.sleep(0.05)
            pixels = np.random.default_rng(0).integers(0, 256, (HEIGHT, WIDTH), dtype=np.uint8).tobytes()

            def send_image(_k: int) -> None:
                image = Image(height=HEIGHT, width=WIDTH, encoding="mono8", step=WIDTH)
                image.data = pixels
                stamp = _stamp(image)
                pubs["in camera"].publish(image)
                arrivals.send("in camera", stamp)

            def send_imu(_k: int) -> None:
                imu = Imu()
                imu.linear_acceleration.z = 9.81
                stamp = _stamp(imu)
                pubs["in imu"].publish(imu)
                arrivals.send("in imu", stamp)

            def send_estimate(stream: str) -> Any:
                def send(k: int) -> None:
                    stamp_s = time.time()
                    payload, attachment = encode(_estimate(stream, k, stamp_s))
                    zpubs[stream].put(payload, attachment=attachment)
                    arrivals.send(stream, stamp_s)

                return send

            rates = {"in camera": args.fps, "in imu": args.imu_hz, "out yaw": args.fps,
                     "out attitude": args.imu_hz, "out pose/vo": args.fps,
                     "out pose/pf": args.fps}  # fmt: skip
            senders = {"in camera": send_image, "in imu": send_imu}
            threads = [
                threading.Thread(
                    target=_paced, args=(stop, rate, senders.get(s) or send_estimate(s)), daemon=True
                )
                for s, rate in rates.items()
            ]
            t_start = time.time()
            for thread in threads:
                thread.start()
            stop.wait(args.seconds)
            stop.set()
            for thread in threads:
                thread.join(2.0)
            time.sleep(1.0)  # the last messages in flight
            for z in zsubs:
                z.undeclare()
        spinner.join(2.0)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return _summary(arrivals, rates, t_start + args.warmup, t_start + args.seconds, args)


def _stamp(msg: Any) -> float:
    ns = time.time_ns()
    msg.header.stamp.sec, msg.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    return ns / 1e9


def _spin(executor: Any, stop: threading.Event) -> None:
    while not stop.is_set():
        executor.spin_once(timeout_sec=0.05)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:  # drain what is still arriving
        executor.spin_once(timeout_sec=0.05)


def _on_zenoh(arrivals: _Arrivals, stream: str, kind: type[WireModel]) -> Any:
    def callback(sample: Any) -> None:
        message: Any = decode(zbytes(sample.payload), zbytes(sample.attachment), kind)
        arrivals.arrived(stream, message.stamp_s)

    return callback


def _summary(
    arrivals: _Arrivals, rates: dict[str, float], t0: float, t1: float, args: argparse.Namespace
) -> dict[str, Any]:
    rows, streams = [], {}
    with arrivals.lock:
        for stream, rate in rates.items():
            sent = [s for s in arrivals.sent[stream] if t0 <= s < t1]
            got = [(s, lat) for s, lat in arrivals.samples[stream] if t0 <= s < t1]
            latency_ms = np.array([lat for _, lat in got]) * 1e3
            window_s = t1 - t0
            entry = {
                "target_hz": rate,
                "sent": len(sent),
                "received": len(got),
                "sent_hz": len(sent) / window_s,
                "received_hz": len(got) / window_s,
                "latency_median_ms": float(np.median(latency_ms)) if got else None,
                "latency_p99_ms": float(np.percentile(latency_ms, 99)) if got else None,
            }
            streams[stream] = entry
            rows.append({
                "stream": stream, "target Hz": f"{rate:g}", "sent Hz": f"{entry['sent_hz']:.1f}",
                "received Hz": f"{entry['received_hz']:.1f}", "lost": len(sent) - len(got),
                "median ms": "-" if not got else f"{entry['latency_median_ms']:.2f}",
                "p99 ms": "-" if not got else f"{entry['latency_p99_ms']:.2f}",
            })  # fmt: skip
    return {
        "json": {
            "bench": NAME,
            "seconds": args.seconds,
            "warmup_s": args.warmup,
            "image": f"{WIDTH}x{HEIGHT} mono8",
            "streams": streams,
            "note": "one process is both ROS 2 node and Zenoh client; latency = send -> receive through DDS "
            "(loopback UDP), the bridge and Zenoh; the host's 2 cores are shared",
        },
        "table": rows,
    }
