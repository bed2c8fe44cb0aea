"""Command-line options every service shares (transport, and the dispatcher's for master and foreman)."""

from __future__ import annotations

import argparse
from enum import Enum
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from common.dispatch import Balance, DispatchSettings, SpeedSource
from services.runtime.options import add_options
from services.runtime.transport import TransportSettings
from services.runtime.usage import UsageError, number_in


def add_enum_argument(parser: Any, flag: str, enum: type[Enum], default: Enum, help: str) -> None:
    """An option taking one of ``enum``'s values (the value string; the settings parse it to the member)."""
    parser.add_argument(flag, choices=[member.value for member in enum], default=default.value, help=help)


def parse_size(text: str, option: str, example: str) -> tuple[int, int]:
    """The two integers of an ``AxB`` option (``--resolution 752x480``, ``--grid 8x5``), or one error line
    (a :class:`UsageError`: exit 2)."""
    try:
        first, second = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise UsageError(f"{option} must look like {example}, got {text!r}") from None
    return first, second


#: the protocols a capataz endpoint may use (zenoh's ``PROTOCOL/ADDRESS[?metadata][#config]``)
ENDPOINT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")


def endpoint(text: str) -> str:
    """An argparse ``type=`` for ``--listen`` / ``--connect``: ``PROTOCOL/ADDRESS`` with a known protocol, or
    one error line naming what is accepted (zenoh's own error is a truncated Rust dump)."""
    protocol, slash, address = str(text).partition("/")
    if not slash or protocol not in ENDPOINT_PROTOCOLS or not address.split("?")[0].split("#")[0]:
        raise argparse.ArgumentTypeError(
            f"must be PROTOCOL/ADDRESS with PROTOCOL one of {', '.join(ENDPOINT_PROTOCOLS)} "
            f"(e.g. tcp/127.0.0.1:7447), got {text!r}"
        )
    return str(text)


def add_transport_arguments(parser: Any, node_default: str = "local", member: bool = True) -> None:
    """Options every service shares (environment ``CAPATAZ_ZENOH_*`` fills what is not given); with
    ``member=False`` (a tool that watches the cluster without joining it) only the transport's."""
    group = parser.add_argument_group("transport (defaults from CAPATAZ_ZENOH_* environment variables)")
    group.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (default peer)")
    group.add_argument(
        "--listen", action="append", type=endpoint, metavar="ENDPOINT", help="listen endpoint (repeatable)"
    )
    group.add_argument(
        "--connect", action="append", type=endpoint, metavar="ENDPOINT", help="connect endpoint (repeatable)"
    )
    group.add_argument(
        "--multicast", action=argparse.BooleanOptionalAction, help="multicast scouting on/off (default off)"
    )
    group.add_argument(
        "--shm", action=argparse.BooleanOptionalAction, help="zenoh shared memory on/off (default off)"
    )
    lease_ms = TransportSettings.model_fields["lease_ms"].default
    group.add_argument("--lease-ms", type=number_in(int, 1), help=f"link lease in ms (default {lease_ms})")
    group.add_argument(
        "--zenoh-config",
        type=Path,
        metavar="FILE",
        help="zenoh configuration file under these settings (access control, TLS, ...; env "
        "CAPATAZ_ZENOH_CONFIG); credentials only from it or CAPATAZ_ZENOH_TLS_{CA,CERT,KEY}, "
        "CAPATAZ_ZENOH_USRPWD_FILE",
    )
    if not member:
        return
    group.add_argument("--node", default=node_default, help=f"node (host) name (default {node_default})")
    group.add_argument(
        "--index", type=number_in(int, 0), default=0, help="instance index on the node (default 0)"
    )
    group.add_argument(
        "--stats-period",
        type=number_in(float, 0.01, 3600.0),
        default=1.0,
        help="seconds between stats messages",
    )


def transport_from_args(args: Any) -> TransportSettings:
    return TransportSettings.from_env(
        mode=args.mode,
        listen=tuple(args.listen) if args.listen else None,
        connect=tuple(args.connect) if args.connect else None,
        multicast_scouting=args.multicast,
        shared_memory=args.shm,
        lease_ms=args.lease_ms,
        zenoh_config=getattr(args, "zenoh_config", None),
    )


def add_dispatch_arguments(parser: argparse.ArgumentParser, compute_help: str) -> None:
    """The dispatcher's options, shared by the master and the foreman (defaults: DispatchSettings())."""
    default = DispatchSettings()
    add_enum_argument(parser, "--balance", Balance, default.balance, help="share balancing")
    parser.add_argument(
        "--compute", action=argparse.BooleanOptionalAction, default=default.self_compute, help=compute_help
    )
    parser.add_argument(
        "--min-deadline-ms", type=float, default=1e3 * default.min_deadline_s,
        help="smallest per-request deadline",
    )  # fmt: skip
    add_enum_argument(
        parser, "--speed", SpeedSource, default.speed_source,
        help="speed measure for time balancing: members' own figures, or round-trip patches/s",
    )  # fmt: skip


def dispatch_from_args(args: argparse.Namespace) -> DispatchSettings:
    """The dispatcher's settings given by :func:`add_dispatch_arguments`' options."""
    return DispatchSettings(
        balance=Balance(args.balance),
        self_compute=args.compute,
        min_deadline_s=args.min_deadline_ms / 1e3,
        speed_source=SpeedSource(args.speed),
    )


#: resident memory of an idle worker or foreman process: interpreter, numpy, OpenCV, zenoh, in MB (VmRSS once
#: alive: worker 82, foreman 83; tests/integration/test_member_memory_budget.py)
IDLE_PROCESS_MB = 90.0

#: what computing one largest share holds beyond the idle process and the cache, in MB (2**20 bytes): the
#: job's payload as zenoh received it and as decoded, its new and previous spectra, the correlation's
#: temporaries (VmHWM less the idle VmRSS of a worker whose cache keeps nothing, serving jobs of 2**24 pixels
#: of 256 px crops with full OpenCV spectra: 377 MB; tests/integration/test_member_memory_budget.py)
LARGEST_SHARE_MB = 400.0


class StreamBoundSettings(BaseModel):
    """Bounds of a member's per-stream state (spectra, dispatchers, crops): the worker's and foreman's."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_streams: int = Field(default=64, ge=1, description="streams kept at most (LRU evicted)")
    stream_ttl_s: float = Field(default=60.0, gt=0.0, description="seconds an unused stream is kept")
    cache_mb: float = Field(
        default=512.0,
        gt=0.0,
        le=65536.0,
        description="memory budget across all streams (MB; LRU evicted beyond it): cached spectra, and a "
        "foreman's previous crops (half each); the whole process stays within this plus its idle size and "
        "one largest job (docs/security.md)",
    )


def add_stream_bound_arguments(parser: argparse.ArgumentParser) -> None:
    """Bounds of the per-stream state (spectra, dispatchers, crops), shared by the foreman and the worker
    (default, bound and help text: :class:`StreamBoundSettings`' fields)."""
    add_options(
        parser,
        StreamBoundSettings,
        ("max_streams", "stream_ttl_s", "cache_mb"),
        flags={"stream_ttl_s": "--stream-ttl"},
    )
