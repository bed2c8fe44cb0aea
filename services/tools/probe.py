"""What the operator's probes share (``capataz status``, ``echo``, ``hz``, ``metrics``): a session of their
own with the transport options of every service (``--connect``, ``--zenoh-config`` for TLS and access
control, ``CAPATAZ_ZENOH_*``), no liveliness token (a probe watches the cluster, it is not a member), a
bound in time or count, and a clean exit (0) on SIGINT or SIGTERM.

:class:`SampleQueue` is a subscriber callback that only stamps a sample's arrival and hands it to a bounded
queue (a full queue drops and counts); the probe's own thread decodes it.
"""

from __future__ import annotations

import argparse
import queue
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
import zenoh

from common.errors import CapatazError
from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Health, Stats
from common.wire.schema import WireError, WireModel
from services.runtime.cli import add_transport_arguments, transport_from_args
from services.runtime.transport import open_session, zbytes
from services.runtime.usage import UsageError


def add_probe_arguments(parser: argparse.ArgumentParser, duration_help: str) -> None:
    """The transport options (no ``--node``/``--index``: a probe is not a member) and ``--duration``."""
    add_transport_arguments(parser, member=False)
    parser.add_argument("--duration", type=float, default=0.0, help=duration_help)


def add_key_probe_arguments(parser: argparse.ArgumentParser, what: str, queue: int) -> None:
    """What ``echo`` and ``hz`` share: the key expression, ``--count`` of ``what`` (messages, reports),
    ``--json``, a bounded ``--queue`` and the probe's own options."""
    parser.add_argument("key", metavar="KEY", help="key expression (capataz/uav/uav0/yaw, capataz/uav/**)")
    parser.add_argument("--count", type=int, default=0, help=f"stop after this many {what} (0 = no limit)")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--queue", type=int, default=queue, help="samples waiting to be handled at most")
    add_probe_arguments(parser, "stop after this many seconds (0 = --count or ^C)")


def decode_stats(sample: zenoh.Sample) -> Stats | None:
    """A member's Stats, or None for a sample that is not one (the caller counts it as malformed)."""
    try:
        return decode(zbytes(sample.payload), zbytes(sample.attachment), Stats)
    except WireError:
        return None


def check_positive(value: float, option: str, allow_zero: bool = False) -> None:
    """A wrong number on the command line: one line naming the option (exit 2 through the CLI)."""
    if not (value >= 0 if allow_zero else value > 0) or value != value:
        raise UsageError(f"{option} must be {'>= 0' if allow_zero else '> 0'}, got {value}")


def check_key_expr(text: str) -> str:
    """A key expression (``capataz/uav/*/yaw``), or one line naming what is wrong with it (exit 2)."""
    try:
        return str(zenoh.KeyExpr(text))
    except zenoh.ZError as exc:
        raise UsageError(
            f"KEY {text!r} is not a key expression ({str(exc).split(':', 1)[-1].strip()})"
        ) from None


def open_probe_session(args: argparse.Namespace) -> zenoh.Session:
    return open_session(transport_from_args(args))


@contextmanager
def stop_on_signals(stop: threading.Event | None = None) -> Iterator[threading.Event]:
    """An event (``stop``, or a new one) set by SIGINT or SIGTERM while inside (main thread only; the old
    handlers are restored)."""
    stop = threading.Event() if stop is None else stop
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@dataclass(frozen=True)
class Arrival:
    """A received sample, raw: when it arrived (``time.monotonic()``), its key and its two byte strings."""

    arrival_s: float
    key: str
    payload: bytes | None
    attachment: bytes | None

    def decode(self) -> WireModel:
        """The message it carries; :class:`WireError` when it carries none."""
        return decode(self.payload, self.attachment)


class SampleQueue:
    """A subscriber callback that queues each sample's :class:`Arrival` (bounded; a full queue drops)."""

    def __init__(self, maxsize: int = 1024, keep_bytes: bool = True) -> None:
        self._queue: queue.Queue[Arrival] = queue.Queue(maxsize)
        self.keep_bytes = keep_bytes
        self.dropped = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        arrival_s = time.monotonic()
        payload = zbytes(sample.payload) if self.keep_bytes else None
        attachment = zbytes(sample.attachment) if self.keep_bytes else None
        try:
            self._queue.put_nowait(Arrival(arrival_s, str(sample.key_expr), payload, attachment))
        except queue.Full:
            self.dropped += 1

    def take(self, timeout_s: float) -> Arrival | None:
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None


class Deadline:
    """``--duration`` seconds from now (0 = none): :meth:`left` bounds each wait."""

    def __init__(self, duration_s: float) -> None:
        self.end = time.monotonic() + duration_s if duration_s > 0 else None

    def passed(self) -> bool:
        return self.end is not None and time.monotonic() >= self.end

    def left(self, step_s: float) -> float:
        return step_s if self.end is None else max(0.0, min(step_s, self.end - time.monotonic()))


def summary_fields(message: WireModel) -> dict[str, Any]:
    """A message's fields for a terminal: scalars as they are, an array as ``<uint8 480x752>`` unless it is
    small (at most 16 values, shown as a list)."""
    fields: dict[str, Any] = {}
    for name, value in message:
        if isinstance(value, np.ndarray):
            if value.size <= 16:
                fields[name] = np.round(value.astype(float), 6).tolist()
            else:
                fields[name] = f"<{value.dtype} {'x'.join(map(str, value.shape))}>"
        elif hasattr(value, "model_dump"):
            fields[name] = value.model_dump(mode="json")
        elif isinstance(value, Enum):
            fields[name] = value.value
        else:
            fields[name] = value
    return fields


def decoded(arrival: Arrival) -> tuple[WireModel | None, str]:
    """The message of an arrival, or None and why not (one line)."""
    try:
        return arrival.decode(), ""
    except WireError as exc:
        return None, str(exc)


class NoMembersError(CapatazError):
    """Nothing answered: no member alive behind the given endpoints (or no endpoint given)."""


def alive_members(session: zenoh.Session, timeout_s: float) -> set[str]:
    """Names (``role/node/i``) of the members whose liveliness token is up."""
    names: set[str] = set()
    for reply in session.liveliness().get(keys.ALIVE_ALL, timeout=timeout_s):
        if reply.ok is not None:
            try:
                names.add(keys.parse_alive_key(str(reply.ok.key_expr)).name)
            except CapatazError:
                continue
    return names


def health_replies(session: zenoh.Session, timeout_s: float) -> tuple[dict[str, Health], int]:
    """Every member's :class:`Health` by name, and how many replies were errors or did not decode.

    Consolidation ``NONE``: every reply, not one per key (replies on one key were merged: 1 of 12 members).
    """
    replies: dict[str, Health] = {}
    bad = 0
    for reply in session.get(keys.HEALTH_ALL, consolidation=zenoh.ConsolidationMode.NONE, timeout=timeout_s):
        try:
            if reply.ok is None:
                raise WireError("error reply")
            health = decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), Health)
        except WireError:
            bad += 1
            continue
        replies[health.member] = health
    return replies, bad
