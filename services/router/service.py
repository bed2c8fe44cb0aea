"""The router: a Python zenoh session in router mode; peers connect to it and then talk directly.

It honours a Zenoh configuration file (``--zenoh-config``, ``CAPATAZ_ZENOH_CONFIG`` or ``ZENOH_CONFIG``):
access control, TLS and authentication come from there (credentials also from ``CAPATAZ_ZENOH_TLS_*``).
Without ``--listen`` it listens where the file says, else on :data:`DEFAULT_ROUTER_ENDPOINT`.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

from common import keys
from services.runtime import zconfig
from services.runtime.transport import (
    ServiceRuntime,
    TransportError,
    TransportSettings,
    add_transport_arguments,
    transport_from_args,
)

logger = logging.getLogger(__name__)
DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterService(ServiceRuntime):
    role = keys.Role.ROUTER


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("router", help="a zenoh router (router-mode Python session)")
    add_transport_arguments(parser, node_default="router")
    parser.set_defaults(handler=run)


def router_transport(args: argparse.Namespace) -> TransportSettings:
    """The router's settings: mode router; the default endpoint only when neither options, environment
    nor the config file say where to listen."""
    args.mode = "router"
    transport = transport_from_args(args)
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
    args.listen = [DEFAULT_ROUTER_ENDPOINT]
    return transport_from_args(args)


def run(args: argparse.Namespace) -> int:
    transport = router_transport(args)
    router = RouterService(args.node, args.index, transport, args.stats_period)
    config = transport.to_config()
    logger.info(
        "router: listen %s, access control %s",
        zconfig.get(config, "listen/endpoints"),
        "on" if zconfig.access_control_enabled(config) else "off",
    )
    return router.run()
