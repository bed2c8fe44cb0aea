"""The router: a Python zenoh session in router mode; peers connect to it and then talk directly."""

from __future__ import annotations

import argparse
from typing import Any

from common import keys
from services.runtime.transport import ServiceRuntime, TransportSettings, add_transport_arguments

DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterService(ServiceRuntime):
    role = keys.Role.ROUTER


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("router", help="a zenoh router (router-mode Python session)")
    add_transport_arguments(parser, node_default="router")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    transport = TransportSettings.from_env(
        mode="router",
        listen=tuple(args.listen) if args.listen else (DEFAULT_ROUTER_ENDPOINT,),
        connect=tuple(args.connect) if args.connect else None,
        multicast_scouting=args.multicast,
        shared_memory=args.shm,
        lease_ms=args.lease_ms,
    )
    return RouterService(args.node, args.index, transport, args.stats_period).run()
