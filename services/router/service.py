"""The router: a Python zenoh session in router mode; peers connect to it and then talk directly."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import zenoh

from common import keys
from services.runtime.cli import add_transport_arguments
from services.runtime.service import ServiceRuntime
from services.runtime.transport import TransportSettings, listening_endpoints

DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterService(ServiceRuntime):
    """A router-mode session; with ``endpoint_file`` it writes the endpoints it really listens on there
    (one per line, written atomically before it declares itself alive), so that a router started on
    ``tcp/127.0.0.1:0`` can be found without reserving a port beforehand."""

    role = keys.Role.ROUTER

    def __init__(self, *args: Any, endpoint_file: Path | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)  # ServiceRuntime's (node, index, transport, stats_period_s)
        self.endpoint_file = endpoint_file

    def start(self, session: zenoh.Session) -> None:
        if self.endpoint_file is not None:
            write_endpoints(self.endpoint_file, listening_endpoints(session))


def write_endpoints(path: Path, endpoints: tuple[str, ...]) -> None:
    """Write ``endpoints`` one per line; a reader never sees a half-written file (write, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    partial.write_text("".join(f"{e}\n" for e in endpoints))
    os.replace(partial, path)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("router", help="a zenoh router (router-mode Python session)")
    add_transport_arguments(parser, node_default="router")
    parser.add_argument(
        "--endpoint-file",
        type=Path,
        help="write the endpoints the router listens on to this file (for --listen tcp/127.0.0.1:0)",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    transport = TransportSettings.from_env(
        mode="router",
        listen=tuple(args.listen) if args.listen else (DEFAULT_ROUTER_ENDPOINT,),
        connect=tuple(args.connect) if args.connect else None,
        multicast_scouting=args.multicast,
        shared_memory=args.shm,
        lease_ms=args.lease_ms,
        admin_space=True if args.endpoint_file else None,
    )
    return RouterService(
        args.node, args.index, transport, args.stats_period, endpoint_file=args.endpoint_file
    ).run()
