"""``capataz metrics --port 9464``: the members' stats as a Prometheus/OpenMetrics endpoint.

One exporter for the whole cluster: it subscribes to ``capataz/stats/**`` (every member publishes its
:class:`~common.wire.messages.Stats` each stats period), polls ``capataz/health/**`` every
``--health-period`` s, and serves the latest of each member at ``http://BIND:PORT/metrics`` with the
``prometheus-client`` library (Prometheus text, or OpenMetrics when the scraper asks for it). Opt-in: run it
by hand or with the compose profile ``metrics``. The metric names (a Grafana-ready list) are in
docs/operations.md; every member's series carry the labels ``role``, ``node``, ``index``, ``host`` and
``uav`` (the UAV streams it serves, comma separated; empty for members of every stream). A member silent
for ``--forget`` s is dropped from the output.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import zenoh
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import CollectorRegistry

from common.errors import CapatazError
from common.wire.messages import Health, Stats
from services.runtime.usage import UsageError
from services.tools.observe import StatsWatch, dropped_count, refused_count
from services.tools.probe import (
    Deadline,
    add_probe_arguments,
    check_positive,
    health_replies,
    open_probe_session,
    stop_on_signals,
)

logger = logging.getLogger(__name__)

#: labels of every member's series
MEMBER_LABELS = ("role", "node", "index", "host", "uav")


@dataclass(frozen=True)
class Seen:
    """A member's latest stats and when they arrived (``time.monotonic()``)."""

    stats: Stats
    arrival_s: float

    def labels(self) -> list[str]:
        s = self.stats
        return [s.role, s.node, str(s.index), s.host, ",".join(s.uavs)]


class StatsExporter:
    """A Prometheus collector of the latest stats (and health) of every member (``registry.register``)."""

    def __init__(self, session: zenoh.Session, forget_s: float = 30.0, health_timeout_s: float = 2.0) -> None:
        self.session = session
        self.forget_s = forget_s
        self.health_timeout_s = health_timeout_s
        self._lock = threading.Lock()
        self._health: dict[str, Health] = {}
        self._bad_health = 0
        self._watch = StatsWatch(session)

    @property
    def messages(self) -> int:
        """Stats messages received."""
        return self._watch.messages

    @property
    def malformed(self) -> int:
        """Stats messages and health replies that did not decode."""
        with self._lock:
            return self._watch.malformed + self._bad_health

    def poll_health(self) -> None:
        """Ask every member for its health (consolidation NONE) and keep the answers."""
        replies, bad = health_replies(self.session, self.health_timeout_s)
        with self._lock:
            self._health = replies
            self._bad_health += bad

    def members(self) -> dict[str, Seen]:
        """The members heard from within ``forget_s`` (older ones are dropped)."""
        self._watch.forget(self.forget_s)
        _, latest, arrival_s = self._watch.window()
        return {name: Seen(stats, arrival_s[name]) for name, stats in latest.items()}

    def describe(self) -> list[Metric]:
        return []  # the families depend on the members: nothing to check at registration

    def collect(self) -> Iterator[Metric]:
        """Every metric family, built afresh from the latest stats at each scrape."""
        members = self.members()
        with self._lock:
            health = dict(self._health)
        messages, malformed = self.messages, self.malformed
        now = time.monotonic()
        labels = list(MEMBER_LABELS)
        up = GaugeMetricFamily(
            "capataz_member_up", "1: the member's stats arrived within --forget", labels=labels
        )
        uptime = GaugeMetricFamily(
            "capataz_member_uptime_seconds", "seconds since the member started", labels=labels
        )
        age = GaugeMetricFamily(
            "capataz_member_stats_age_seconds", "seconds since its last stats", labels=labels
        )
        healthy = GaugeMetricFamily(
            "capataz_member_healthy", "1 healthy, 0 degraded (its health query; the reason is in status)",
            labels=labels,
        )  # fmt: skip
        events = CounterMetricFamily(
            "capataz_events",
            "the member's counters (inputs, outputs, refusals...)",
            labels=[*labels, "event"],
        )
        refused = CounterMetricFamily(
            "capataz_refused", "inputs refused: malformed, foreign, out of range, no room", labels=labels
        )
        dropped = CounterMetricFamily("capataz_dropped_frames", "frames replaced unread", labels=labels)
        timing = GaugeMetricFamily(
            "capataz_timing_median_seconds", "median duration of a step over the last stats period",
            labels=[*labels, "step"],
        )  # fmt: skip
        queue = GaugeMetricFamily(
            "capataz_queue_depth", "items waiting in a queue", labels=[*labels, "queue"]
        )
        share = GaugeMetricFamily(
            "capataz_share_ratio", "share of the work a dispatcher gives a member", labels=[*labels, "to"]
        )
        for name, seen in sorted(members.items()):
            stats, values = seen.stats, seen.labels()
            up.add_metric(values, 1.0)
            uptime.add_metric(values, stats.uptime_s)
            age.add_metric(values, now - seen.arrival_s)
            if name in health:
                healthy.add_metric(values, 1.0 if health[name].ok else 0.0)
            for event, count in sorted(stats.counters.items()):
                events.add_metric([*values, event], float(count))
            refused.add_metric(values, float(refused_count(stats.counters)))
            dropped.add_metric(values, float(dropped_count(stats.counters)))
            for step, ms in sorted(stats.timings_ms.items()):
                timing.add_metric([*values, step], ms / 1e3)
            for name_q, depth in sorted(stats.queue_depths.items()):
                queue.add_metric([*values, name_q], float(depth))
            for target, fraction in sorted(stats.shares.items()):
                share.add_metric([*values, target], fraction)
        yield from (up, uptime, age, healthy, events, refused, dropped, timing, queue, share)
        heard = GaugeMetricFamily("capataz_exporter_members", "members the exporter hears from")
        heard.add_metric([], float(len(members)))
        received = CounterMetricFamily("capataz_exporter_stats_messages", "stats messages received")
        received.add_metric([], float(messages))
        bad = CounterMetricFamily("capataz_exporter_malformed", "stats or health replies that did not decode")
        bad.add_metric([], float(malformed))
        yield from (heard, received, bad)

    def close(self) -> None:
        self._watch.close()


def serve(
    args: argparse.Namespace, started: threading.Event | None = None, stop: threading.Event | None = None
) -> int:
    """Serve the endpoint until SIGINT/SIGTERM, ``stop`` or ``--duration``; ``started`` is set once it
    listens (its port in ``args.bound_port``)."""
    from prometheus_client import start_http_server

    registry = CollectorRegistry(auto_describe=False)
    deadline = Deadline(args.duration)
    with stop_on_signals(stop) as stop, open_probe_session(args) as session:
        exporter = StatsExporter(session, args.forget)
        registry.register(exporter)
        try:
            server, thread = start_http_server(args.port, addr=args.bind, registry=registry)
        except OSError as exc:
            exporter.close()
            raise CapatazError(f"--port {args.port}: cannot listen on {args.bind} ({exc.strerror})") from None
        args.bound_port = server.server_address[1]
        logger.info("metrics on http://%s:%d/metrics", args.bind, args.bound_port)
        if started is not None:
            started.set()
        try:
            while not stop.is_set() and not deadline.passed():
                exporter.poll_health()
                stop.wait(deadline.left(args.health_period))
        finally:
            server.shutdown()
            server.server_close()
            thread.join(5.0)
            exporter.close()
    return 0


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "metrics", help="serve the members' stats as a Prometheus/OpenMetrics endpoint"
    )
    parser.add_argument("--port", type=int, default=9464, help="HTTP port of /metrics (0 = any free port)")
    parser.add_argument("--bind", default="127.0.0.1", help="address the endpoint listens on (0.0.0.0: all)")
    parser.add_argument("--health-period", type=float, default=5.0, help="seconds between health polls")
    parser.add_argument(
        "--forget", type=float, default=30.0, help="seconds after which a silent member is dropped"
    )
    add_probe_arguments(parser, "stop after this many seconds (0 = until ^C)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port must be in 0..65535, got {args.port}")
    check_positive(args.health_period, "--health-period")
    check_positive(args.forget, "--forget")
    check_positive(args.duration, "--duration", allow_zero=True)
    return serve(args)
