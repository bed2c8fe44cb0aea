"""A small observer run inside an emulated host (``ip netns exec <ns> python -m services.tools.netns_agent``).

A process whose Zenoh sessions live in the root namespace cannot reach addresses that exist only inside the
harness's namespaces (:mod:`services.tools.netns`), so whatever watches or probes the emulated network runs
in one of its hosts as this agent, and talks to its parent through lines on stdout: ``ready`` once its
subscriber/queryable is declared, then one JSON object with the result. Every wait is bounded; bad input is
one line on stderr and exit code 2.

Modes (each takes ``--connect`` its host's router and ``--listen`` its host's address):

- ``alive NAME...``: waits until each member has a liveliness token; ``{"alive": [...], "missing": [...]}``.
- ``yaw --uav U --count N``: collects the UAV's yaw estimates; ``{"seqs": [...], "members": {...},
  "redispatched": n, "median_timings_ms": {...}, "frames": [[seq, members, total_ms], ...]}`` (patches per
  member, shares re-dispatched, the master's stage timings' medians; each frame's members and frame-in to
  yaw-out time).
- ``sub KEY``: the first sample's payload size and text head; ``put KEY TEXT``: puts once a subscriber
  matches.
- ``serve KEY --size B``: replies ``B`` bytes to every query until stdin closes; ``get KEY``: one query
  answered, ``{"bytes": n, "seconds": t}`` (the time of that query alone).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from collections import Counter
from typing import Any

import zenoh

from common.errors import CapatazError
from services.runtime.transport import TransportSettings, open_session
from services.tools.observe import AliveWatch, YawCollector, median_timings_ms


def _say(line: str) -> None:
    print(line, flush=True)


def _transport(args: argparse.Namespace) -> TransportSettings:
    return TransportSettings(listen=(args.listen,), connect=(args.connect,), lease_ms=2000)


def _alive(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    wanted = set(args.names)
    watch = AliveWatch(session)
    _say("ready")
    watch.wait_for(wanted, args.timeout)
    seen = watch.names()
    watch.close()
    return {"alive": sorted(seen & wanted), "missing": sorted(wanted - seen)}


def _yaw(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    collector = YawCollector(session, args.uav)
    _say("ready")
    collector.wait_for(args.count, args.timeout)
    estimates = dict(collector.estimates)
    collector.close()
    members: Counter[str] = Counter()
    for estimate in estimates.values():
        members.update(estimate.members)
    frames = [[seq, e.members, e.timings_ms.get("total")] for seq, e in sorted(estimates.items())]
    return {"seqs": sorted(estimates), "members": dict(members), "malformed": collector.malformed,
            "redispatched": sum(e.redispatched for e in estimates.values()),
            "median_timings_ms": median_timings_ms(estimates.values()), "frames": frames}  # fmt: skip


def _sub(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    got: list[bytes] = []
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        if not done.is_set():
            got.append(sample.payload.to_bytes())
            done.set()

    sub = session.declare_subscriber(args.key, on_sample)
    _say("ready")
    done.wait(args.timeout)
    sub.undeclare()
    return {"received": len(got), "text": got[0][:64].decode(errors="replace") if got else None}


def _put(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    publisher = session.declare_publisher(args.key)
    _say("ready")
    deadline = time.monotonic() + args.timeout
    status: Any = publisher.matching_status  # zenoh's stub says bool; it is an object with .matching
    while not status.matching and time.monotonic() < deadline:
        time.sleep(0.02)
        status = publisher.matching_status
    matched = bool(status.matching)
    if matched:
        publisher.put(args.text.encode())
    publisher.undeclare()
    return {"matched": matched}


def _serve(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    body = bytes(args.size)
    served = 0

    def on_query(query: zenoh.Query) -> None:
        nonlocal served
        with query:
            query.reply(args.key, body)
        served += 1

    queryable = session.declare_queryable(args.key, on_query, complete=True)
    _say("ready")
    sys.stdin.read()  # the parent closes stdin (or the process is signalled) when the test is done
    queryable.undeclare()
    return {"served": served}


def _get(session: zenoh.Session, args: argparse.Namespace) -> dict[str, Any]:
    _say("ready")
    deadline = time.monotonic() + args.timeout
    while time.monotonic() < deadline:  # no reply at once while the queryable is not routed yet: ask again
        t0 = time.perf_counter()
        replies = list(session.get(args.key, timeout=max(1.0, deadline - time.monotonic())))
        seconds = time.perf_counter() - t0
        for reply in replies:
            if reply.ok is not None:
                return {"bytes": len(reply.ok.payload.to_bytes()), "seconds": seconds}
        time.sleep(0.05)
    return {"bytes": 0, "seconds": None}


MODES = {"alive": _alive, "yaw": _yaw, "sub": _sub, "put": _put, "serve": _serve, "get": _get}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="netns_agent", description=__doc__.split("\n")[0])
    p.add_argument("--connect", required=True, help="the host's router endpoint")
    p.add_argument("--listen", required=True, help="this agent's listen endpoint (the host's address)")
    p.add_argument("--timeout", type=float, default=30.0, help="bound of the wait (s)")
    modes = p.add_subparsers(dest="mode", required=True)
    modes.add_parser("alive").add_argument("names", nargs="+")
    yaw = modes.add_parser("yaw")
    yaw.add_argument("--uav", default="uav0")
    yaw.add_argument("--count", type=int, required=True)
    modes.add_parser("sub").add_argument("key")
    put = modes.add_parser("put")
    put.add_argument("key")
    put.add_argument("text")
    serve = modes.add_parser("serve")
    serve.add_argument("key")
    serve.add_argument("--size", type=int, required=True)
    modes.add_parser("get").add_argument("key")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.timeout <= 0 or getattr(args, "size", 0) < 0 or getattr(args, "count", 1) < 1:
        print("netns_agent: --timeout, --count must be > 0 and --size >= 0", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(0))
    try:
        with open_session(_transport(args)) as session:
            result = MODES[args.mode](session, args)
    except CapatazError as exc:
        print(f"netns_agent: {exc}", file=sys.stderr)
        return 2
    _say(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
