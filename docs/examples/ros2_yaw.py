"""Read capataz's yaw on ROS 2 as a ROS 2 node would (the README's quick-start).

    python docs/examples/ros2_yaw.py --domain-id 42 --count 20

The node joins the bridge's graph with the same DDS environment (Fast DDS on loopback, unicast, the
bridge's domain): ``services.ros2.dds`` writes the profile and sets the variables before rclpy starts.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from services.ros2.dds import apply_environment, dds_environment, write_profile

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--domain-id", type=int, default=42, help="the bridge's --domain-id")
parser.add_argument("--uav", default="uav0")
parser.add_argument("--count", type=int, default=20, help="stop after this many estimates")
parser.add_argument("--timeout", type=float, default=120.0, help="give up after this many seconds")
args = parser.parse_args()
apply_environment(dds_environment(write_profile(Path("out/ros2/fastdds_loopback.xml")), args.domain_id))

import rclpy  # noqa: E402 (the DDS environment must be set first)
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import Imu  # noqa: E402

received = 0


def on_yaw(message: Imu) -> None:
    global received
    q = message.orientation
    stamp_s = message.header.stamp.sec + 1e-9 * message.header.stamp.nanosec
    sigma_rad = message.orientation_covariance[8] ** 0.5
    print(f"{stamp_s:.3f} s: yaw quaternion z {q.z:+.5f} w {q.w:+.5f}, sigma {sigma_rad:.4f} rad")
    received += 1


rclpy.init()
node = rclpy.create_node("capataz_yaw_reader")
node.create_subscription(Imu, f"/{args.uav}/capataz/yaw", on_yaw, qos_profile_sensor_data)
deadline = time.monotonic() + args.timeout
while received < args.count and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
node.destroy_node()
rclpy.shutdown()
raise SystemExit(0 if received >= args.count else f"only {received} of {args.count} yaw estimates")
