"""``capataz status [--watch]``: every member of a running cluster, as an operator needs to see it.

Over a window (``--window`` s, two stats periods by default) it gathers, from a session of its own:

- who is alive: a liveliness query on ``capataz/alive/**``;
- each member's health: a query on ``capataz/health/**`` with consolidation ``NONE`` (every member answers
  on its own key; the default consolidation merged replies that shared the query's key: 1 of 12 members);
- each member's stats (``capataz/stats/**``): host, UAV streams, uptime, queue depths, refusals, and per
  counter the rate between the first and the last stats message of the window;
- the rate of every stream key (``capataz/uav/**``, counted, not decoded; ``--no-streams`` skips it).

It prints two plain tables (members, streams) or, with ``--json``, one JSON document; ``--watch`` repeats
every window until SIGINT/SIGTERM or ``--duration``. Exit 1 (one line) when no member answered.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

import zenoh

from common.rates import counter_rates
from common.wire import keys
from common.wire.messages import Health, Stats
from services.tools.observe import AliveWatch, StatsWatch, dropped_count, refused_count
from services.tools.probe import (
    Deadline,
    NoMembersError,
    SampleQueue,
    add_probe_arguments,
    check_positive,
    health_replies,
    open_probe_session,
    stop_on_signals,
)
from services.tools.report import print_table

#: the stream keys whose rates ``status`` shows
STREAMS = f"{keys.ROOT}/uav/**"
#: seconds after which the stats of a member that left are forgotten (``--watch``)
FORGET_S = 30.0


@dataclass
class MemberStatus:
    """What one member showed during a window (``None``: it did not show it)."""

    name: str
    alive: bool = False
    health: Health | None = None
    first: Stats | None = None
    stats: Stats | None = None

    @property
    def rates(self) -> dict[str, float]:
        """Per-second rate of each counter between the window's first and last stats message."""
        if self.first is None or self.stats is None or self.stats.uptime_s <= self.first.uptime_s:
            return {}
        return counter_rates(
            self.first.counters, self.stats.counters, self.stats.uptime_s - self.first.uptime_s
        )

    @property
    def state(self) -> str:
        if self.health is None:
            return "alive, no health" if self.alive else "gone"
        return "ok" if self.health.ok else "DEGRADED"

    def row(self) -> dict[str, Any]:
        """One line of the members table."""
        stats, rates = self.stats, self.rates
        counters = stats.counters if stats else self.health.counters if self.health else {}
        busiest = sorted(((r, k) for k, r in rates.items() if r > 0), reverse=True)[:4]
        uptime = stats.uptime_s if stats else self.health.uptime_s if self.health else float("nan")
        return {
            "member": self.name,
            "host": (stats.host if stats else "") or "-",
            "uav": ",".join(stats.uavs) if stats and stats.uavs else "-",
            "up s": round(uptime, 1),
            "health": self.state,
            "why": (self.health.detail if self.health and not self.health.ok else "") or "-",
            "rates /s": ", ".join(f"{k} {r:.3g}" for r, k in busiest) or "-",
            "queues": ", ".join(f"{k}={v}" for k, v in sorted(stats.queue_depths.items())) if stats else "-",
            "refused": refused_count(counters),
            "dropped": dropped_count(counters),
        }

    def document(self) -> dict[str, Any]:
        """Everything known of the member (``--json``)."""
        return {
            "member": self.name,
            "alive": self.alive,
            "state": self.state,
            "health": None if self.health is None else self.health.model_dump(),
            "stats": None if self.stats is None else self.stats.model_dump(),
            "rates_per_s": self.rates,
        }


@dataclass
class StreamRate:
    key: str
    messages: int = 0
    first_s: float = 0.0
    last_s: float = 0.0

    @property
    def rate_hz(self) -> float:
        """Messages per second between the first and the last arrival of the window."""
        span = self.last_s - self.first_s
        return (self.messages - 1) / span if self.messages > 1 and span > 0 else float("nan")


@dataclass
class Snapshot:
    """One window's view of the cluster."""

    window_s: float
    members: dict[str, MemberStatus]
    streams: dict[str, StreamRate] = field(default_factory=dict)
    malformed: int = 0

    def document(self) -> dict[str, Any]:
        return {
            "window_s": self.window_s,
            "members": [m.document() for _, m in sorted(self.members.items())],
            "streams": [
                {"key": s.key, "messages": s.messages, "rate_hz": s.rate_hz} for s in self.streams.values()
            ],
            "malformed": self.malformed,
        }


class ClusterObserver:
    """Subscriptions to stats (and streams) that stay declared across windows (``--watch``)."""

    def __init__(self, session: zenoh.Session, streams: str | None, timeout_s: float) -> None:
        self.session = session
        self.timeout_s = timeout_s
        self._stats = StatsWatch(session)
        self._streams = SampleQueue(1 << 16, keep_bytes=False)
        self._alive = AliveWatch(session)
        self._subscribers = [session.declare_subscriber(streams, self._streams)] if streams else []

    def snapshot(self, window_s: float, stop: threading.Event) -> Snapshot:
        """The streams' rates and the members' stats over ``window_s``, then who is alive and their health.

        The queries come at the end of the window: a query sent as soon as the session opened reached only
        the members whose routes had arrived yet (5 of 7 in a run).
        """
        self._stats.start_window()  # rates over this window start at the last message seen
        t0 = time.monotonic()
        streams: dict[str, StreamRate] = {}
        deadline = Deadline(window_s)
        while not stop.is_set():
            arrival = self._streams.take(deadline.left(0.05))
            if arrival is not None:
                rate = streams.setdefault(arrival.key, StreamRate(arrival.key, 0, arrival.arrival_s))
                rate.messages += 1
                rate.last_s = arrival.arrival_s
            elif deadline.passed():
                break
        health, bad = health_replies(self.session, self.timeout_s)
        alive = self._alive.names()
        # a member that left is listed as gone while its last stats are recent, then forgotten
        self._stats.forget(FORGET_S, keep=frozenset(alive))
        first, latest, _ = self._stats.window()
        malformed = self._stats.malformed
        names = alive | set(health) | set(latest)
        members = {
            n: MemberStatus(n, n in alive, health.get(n), first.get(n), latest.get(n)) for n in sorted(names)
        }
        return Snapshot(time.monotonic() - t0, members, dict(sorted(streams.items())), malformed + bad)

    def close(self) -> None:
        self._stats.close()
        self._alive.close()
        for subscriber in self._subscribers:
            subscriber.undeclare()


def render(snapshot: Snapshot, out: TextIO) -> None:
    members = snapshot.members.values()
    degraded = sum(1 for m in members if m.state != "ok")
    print_table(
        [m.row() for m in members],
        title=f"{len(snapshot.members)} members, {degraded} not ok (window {snapshot.window_s:.1f} s)",
        file=out,
    )
    if snapshot.streams:
        print(file=out)
        rows = [
            {"key": s.key, "rate Hz": s.rate_hz, "messages": s.messages} for s in snapshot.streams.values()
        ]
        print_table(rows, title="streams", file=out)
    if snapshot.malformed:
        print(f"{snapshot.malformed} stats or health messages did not decode", file=out)


def status(args: argparse.Namespace, out: TextIO | None = None) -> list[Snapshot]:
    """One snapshot (or one per window with ``--watch``), printed; returns them."""
    out = sys.stdout if out is None else out
    snapshots: list[Snapshot] = []
    deadline = Deadline(args.duration)
    with stop_on_signals() as stop, open_probe_session(args) as session:
        observer = ClusterObserver(session, None if args.no_streams else STREAMS, args.timeout)
        try:
            while not stop.is_set():
                snapshot = observer.snapshot(args.window, stop)
                snapshots.append(snapshot)
                if not snapshot.members and len(snapshots) == 1:
                    break  # nobody there: one error line below, no empty table
                if args.json:
                    print(json.dumps(snapshot.document()), file=out, flush=True)
                else:
                    if args.watch and out.isatty():
                        print("\x1b[2J\x1b[H", end="", file=out)
                    render(snapshot, out)
                    out.flush()
                if not args.watch or deadline.passed():
                    break
        finally:
            observer.close()
    if not snapshots[-1].members and not stop.is_set():
        raise NoMembersError(
            f"no member answered within {args.window:.1f} s "
            f"(connect: {', '.join(args.connect or []) or 'none'})"
        )
    return snapshots


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "status", help="every member: role, node, host, uptime, health (and why), rates, queues, refusals"
    )
    parser.add_argument("--watch", action="store_true", help="repeat every window until ^C or --duration")
    parser.add_argument("--window", type=float, default=2.5, help="seconds over which rates are measured")
    parser.add_argument(
        "--timeout", type=float, default=2.0, help="seconds the liveliness and health queries wait"
    )
    parser.add_argument("--json", action="store_true", help="one JSON document per window (for scripts)")
    parser.add_argument(
        "--no-streams", action="store_true", help="do not measure the rates of capataz/uav/**"
    )
    add_probe_arguments(parser, "with --watch: stop after this many seconds (0 = until ^C)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    check_positive(args.window, "--window")
    check_positive(args.timeout, "--timeout")
    check_positive(args.duration, "--duration", allow_zero=True)
    status(args)
    return 0
