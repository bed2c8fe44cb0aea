"""``capataz master``: its command line (settings in :mod:`services.master.settings`)."""

from __future__ import annotations

import argparse
from typing import Any

from common.wire.messages import YawEstimate
from services.master.service import MasterService
from services.master.settings import add_master_arguments, master_settings_from_args
from services.runtime.cli import add_transport_arguments
from services.runtime.trajectory import register_estimating_service


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_transport_arguments(parser)
    add_master_arguments(parser)


def start(args: argparse.Namespace) -> MasterService:
    return MasterService.from_args(args, master_settings_from_args(args))


def register(subparsers: Any) -> None:
    register_estimating_service(
        subparsers,
        "master",
        "a master: splits each frame of a UAV stream and publishes yaw",
        add_arguments,
        start,
        {YawEstimate: ("--trajectory", "the published yaw (rotation about world z)")},
    )
