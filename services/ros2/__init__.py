"""``capataz ros2``: the bridge between a ROS 2 graph and the Zenoh keys of one or more UAVs.

Needs the ``ros2`` extra (``pip install 'capataz[ros2]'``: rclpy, Fast DDS and the message packages as
wheels); without it the command says so in one line and exits 1. The conversions
(:mod:`services.ros2.convert`), the DDS profile (:mod:`services.ros2.dds`) and the input gates
(:mod:`services.ros2.inputs`) import nothing of ROS.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Any

from services.ros2.dds import MAX_DOMAIN_ID
from services.ros2.settings import Ros2Settings
from services.runtime.cli import add_transport_arguments

#: the one line ``capataz ros2`` prints without the extra
MISSING_EXTRA = (
    "capataz ros2 needs the ROS 2 extra (rclpy, Fast DDS, message packages): pip install 'capataz[ros2]'"
)
#: the modules the bridge imports from the extra
EXTRA_MODULES = ("rclpy", "sensor_msgs", "geometry_msgs")


def extra_installed() -> bool:
    """True when the ``ros2`` extra's modules can be imported."""
    try:
        for name in EXTRA_MODULES:
            importlib.import_module(name)
    except ImportError:
        return False
    return True


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("ros2", help="bridge a ROS 2 graph and the UAV streams (extra: ros2)")
    add_transport_arguments(parser, node_default="ros2")
    parser.add_argument(
        "--uav", action="append", help="UAV whose estimates go out to ROS 2 (repeatable; default uav0)"
    )
    parser.add_argument(
        "--input-uav",
        action="append",
        default=[],
        help="UAV whose sensors come in from ROS 2 onto its capataz streams (repeatable; default none)",
    )
    parser.add_argument(
        "--domain-id", type=int, default=0, help=f"ROS_DOMAIN_ID (0..{MAX_DOMAIN_ID}, default 0)"
    )
    parser.add_argument(
        "--dds-profile",
        type=Path,
        help="Fast DDS profile (default: the loopback-only one, written to out/ros2/fastdds_loopback.xml)",
    )
    parser.add_argument(
        "--calibration-out",
        type=Path,
        help="write each input UAV's CameraInfo as an OpenCV YAML calibration ({uav} is replaced)",
    )
    parser.add_argument(
        "--build-tf2-msgs",
        action="store_true",
        help="build the tf2_msgs package (for /tf_static; PyPI has no wheel) into this environment and exit",
    )
    parser.set_defaults(handler=run)


def settings_from_args(args: argparse.Namespace) -> Ros2Settings:
    return Ros2Settings(
        uavs=tuple(args.uav or ["uav0"]),
        input_uavs=tuple(args.input_uav),
        domain_id=args.domain_id,
        dds_profile=args.dds_profile,
        calibration_out=args.calibration_out,
    )


def run(args: argparse.Namespace) -> int:
    if not extra_installed():
        print(MISSING_EXTRA, file=sys.stderr)
        return 1
    if args.build_tf2_msgs:
        from services.ros2 import tf2_msgs_build

        return tf2_msgs_build.main([])
    from services.ros2.bridge import Ros2Bridge

    return Ros2Bridge.from_args(args, settings_from_args(args)).run()
