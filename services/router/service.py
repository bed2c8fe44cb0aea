"""The router: a Python zenoh session in router mode; peers connect to it and then talk directly.

It honours a Zenoh configuration file (``--zenoh-config``, ``CAPATAZ_ZENOH_CONFIG`` or ``ZENOH_CONFIG``):
access control, TLS and authentication come from there (credentials also from ``CAPATAZ_ZENOH_TLS_*``).
Without ``--listen`` it listens where the file says, else on :data:`DEFAULT_ROUTER_ENDPOINT`.
"""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path
from typing import Any

import zenoh

from common.members import Role
from services.runtime import zconfig
from services.runtime.cli import add_transport_arguments, transport_from_args
from services.runtime.service import ServiceRuntime
from services.runtime.transport import TransportError, TransportSettings, listening_endpoints

logger = logging.getLogger(__name__)
DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterService(ServiceRuntime):
    """A router-mode session; with ``endpoint_file`` it writes the endpoints it really listens on there
    (one per line, written atomically before it declares itself alive), so that a router started on
    ``tcp/127.0.0.1:0`` can be found without reserving a port beforehand."""

    role = Role.ROUTER

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


def router_transport(args: argparse.Namespace) -> TransportSettings:
    """The router's settings: mode router; the default endpoint only when neither options, environment
    nor the config file say where to listen."""
    args.mode = "router"
    transport = transport_from_args(args)
    if args.endpoint_file:
        transport = transport.model_copy(update={"admin_space": True})
    if "listen" in transport.model_fields_set:
        return transport
    try:
        file_listens = transport.zenoh_config is not None and zconfig.file_sets(
            zconfig.load_config(transport.zenoh_config), "listen/endpoints"
        )
    except zconfig.ZenohConfigError as exc:
        raise TransportError(str(exc)) from None
    if file_listens:
        return transport
    return transport.model_copy(update={"listen": (DEFAULT_ROUTER_ENDPOINT,)})


def run(args: argparse.Namespace) -> int:
    transport = router_transport(args)
    config = transport.to_config()
    logger.info(
        "router: listen %s, access control %s",
        zconfig.get(config, "listen/endpoints"),
        "on" if zconfig.access_control_enabled(config) else "off",
    )
    return RouterService(
        args.node, args.index, transport, args.stats_period, endpoint_file=args.endpoint_file
    ).run()
