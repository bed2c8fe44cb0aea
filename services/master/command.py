"""``capataz master``: its command line (settings in :mod:`services.master.settings`)."""

from __future__ import annotations

import argparse
from typing import Any

from common.wire.messages import YawEstimate
from services.master.service import MasterService
from services.master.settings import add_master_arguments, master_settings_from_args
from services.runtime.cli import add_transport_arguments
from services.runtime.trajectory import add_trajectory_argument, run_with_trajectories


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "master", help="a master: splits each frame of a UAV stream and publishes yaw"
    )
    add_transport_arguments(parser)
    add_master_arguments(parser)
    add_trajectory_argument(parser, "the published yaw (rotation about world z)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    service = MasterService.from_args(args, master_settings_from_args(args))
    return run_with_trajectories(service, {YawEstimate: args.trajectory})
