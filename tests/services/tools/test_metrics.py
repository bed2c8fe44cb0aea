"""``capataz metrics``: the stats members publish, scraped over HTTP on 127.0.0.1 and read with the
``prometheus-client`` parser, per member with its labels, values equal to the Stats published; a member's
health (from its health queryable) as ``capataz_member_healthy``; OpenMetrics on request."""

from __future__ import annotations

import argparse
import re
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from prometheus_client.parser import text_string_to_metric_families

from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import Health, Stats
from services.runtime.transport import open_session
from services.tools.cli import build_parser
from services.tools.metrics import serve
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

ROOT = Path(__file__).resolve().parents[3]

MASTER = Stats(
    role="master", node="m1", index=0, uptime_s=12.5, stamp_s=time.time(), host="ground-1", uavs=["uav0"],
    counters={"frames_in": 240, "malformed": 2, "queue_full": 1, "frames_dropped": 4},
    timings_ms={"round": 7.25, "fit": 0.5}, queue_depths={"frames": 1},
    shares={"foreman/h1/0": 0.75, "foreman/h2/0": 0.25},
)  # fmt: skip
WORKER = Stats(
    role="worker", node="h1", index=3, uptime_s=30.0, stamp_s=time.time(), host="ground-2",
    counters={"jobs": 120, "patches": 2400}, timings_ms={"compute": 1.5}, queue_depths={"jobs": 0},
)  # fmt: skip


def scrape(port: int, accept: str | None = None) -> str:
    request = urllib.request.Request(f"http://127.0.0.1:{port}/metrics")
    if accept:
        request.add_header("Accept", accept)
    with urllib.request.urlopen(request, timeout=10) as response:
        return str(response.read().decode())


def samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """Every sample of the exposition by (name, sorted labels), read with prometheus-client's parser."""
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def member(stats: Stats, **extra: str) -> tuple[tuple[str, str], ...]:
    labels = {"role": stats.role, "node": stats.node, "index": str(stats.index), "host": stats.host,
              "uav": ",".join(stats.uavs), **extra}  # fmt: skip
    return tuple(sorted(labels.items()))


def test_the_endpoint_serves_each_members_stats_as_published() -> None:
    with hub() as endpoint, open_session(peer(endpoint)) as session:
        # the master answers health (degraded); the worker has no health queryable
        def on_health(query: Any) -> None:
            health = Health(role="master", node="m1", index=0, uptime_s=12.5, ok=False, detail="degraded: x")
            payload, attachment = encode(health)
            query.reply(keys.health_key("master", "m1", 0), payload, attachment=attachment)

        queryable = session.declare_queryable(keys.health_key("master", "m1", 0), on_health)
        publishers = {
            s.role: session.declare_publisher(keys.stats_key(s.role, s.node, s.index))
            for s in (MASTER, WORKER)
        }
        args: argparse.Namespace = build_parser(("services.tools.metrics",)).parse_args(
            ["metrics", "--port", "0", "--connect", endpoint, "--health-period", "0.2"]
        )
        started, stop = threading.Event(), threading.Event()
        exporter = threading.Thread(target=serve, args=(args, started, stop), daemon=True)
        exporter.start()
        try:
            assert started.wait(WAIT_S)
            assert all(matched(p) for p in publishers.values())
            stats = {"master": MASTER, "worker": WORKER}

            def served() -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
                for role, publisher in publishers.items():  # each period, as a member does
                    payload, attachment = encode(stats[role])
                    publisher.put(payload, attachment=attachment)
                return samples(scrape(args.bound_port))

            values: dict[tuple[str, tuple[tuple[str, str], ...]], float] = {}

            def complete() -> bool:
                values.update(served())
                return ("capataz_member_up", member(WORKER)) in values and (
                    "capataz_member_healthy", member(MASTER)) in values  # fmt: skip

            assert wait_until(complete, WAIT_S, interval_s=0.1), sorted(values)
            openmetrics = scrape(args.bound_port, "application/openmetrics-text; version=1.0.0")
        finally:
            stop.set()
            exporter.join(WAIT_S)
            queryable.undeclare()
    assert not exporter.is_alive()

    for s in (MASTER, WORKER):
        assert values["capataz_member_up", member(s)] == 1.0
        assert values["capataz_member_uptime_seconds", member(s)] == s.uptime_s
        for event, count in s.counters.items():
            assert values["capataz_events_total", member(s, event=event)] == count
        for step, ms in s.timings_ms.items():
            assert values["capataz_timing_median_seconds", member(s, step=step)] == pytest.approx(ms / 1e3)
        for queue, depth in s.queue_depths.items():
            assert values["capataz_queue_depth", member(s, queue=queue)] == depth
    assert values["capataz_refused_total", member(MASTER)] == 3  # malformed + queue_full
    assert values["capataz_dropped_frames_total", member(MASTER)] == 4
    assert values["capataz_share_ratio", member(MASTER, to="foreman/h1/0")] == 0.75
    assert values["capataz_member_healthy", member(MASTER)] == 0.0
    assert ("capataz_member_healthy", member(WORKER)) not in values  # no health answer: no series
    assert values["capataz_exporter_members", ()] == 2
    assert openmetrics.rstrip().endswith("# EOF")
    # the documented list (docs/operations.md, the Grafana-ready table) is what the endpoint serves
    table = (ROOT / "docs" / "operations.md").read_text().split("| metric | type |", 1)[1].split("\n\n", 1)[0]
    documented = set(re.findall(r"^\| `(capataz_[a-z_]+)`", table, re.M))
    assert documented == {name for name, _labels in values}
    assert samples(openmetrics)["capataz_events_total", member(WORKER, event="jobs")] == 120
