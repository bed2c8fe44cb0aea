"""``capataz hz KEY``: the rate of a key expression, like ``ros2 topic hz``.

Every ``--every`` seconds it prints, over the last ``--window`` arrivals (receiver's clock), the mean rate
(one over the mean interval) and the minimum, maximum and standard deviation of the intervals
(:func:`common.rates.interval_stats`); with several keys under one expression, one line per key
(``--per-key``), and once more at the end. Bounded by ``--duration`` or ``--count`` reports; SIGINT/SIGTERM
end it cleanly (exit 0).
Payloads are not decoded: only arrivals count.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import deque
from typing import Any, TextIO

from common.rates import IntervalStats, interval_stats
from services.runtime.usage import UsageError
from services.tools.probe import (
    Deadline,
    SampleQueue,
    add_key_probe_arguments,
    check_key_expr,
    check_positive,
    open_probe_session,
    stop_on_signals,
)


class RateWindow:
    """The last ``window`` arrival times of each key (or of the whole expression under one name)."""

    def __init__(self, window: int, per_key: bool, name: str) -> None:
        self.window = window
        self.per_key = per_key
        self.name = name
        self.arrivals: dict[str, deque[float]] = {}
        self.total = 0

    def add(self, key: str, arrival_s: float) -> None:
        slot = key if self.per_key else self.name
        self.arrivals.setdefault(slot, deque(maxlen=self.window)).append(arrival_s)
        self.total += 1

    def figures(self) -> dict[str, IntervalStats | None]:
        return {key: interval_stats(list(times)) for key, times in sorted(self.arrivals.items())}


def report_line(key: str, figures: IntervalStats | None, as_json: bool) -> str:
    if as_json:
        values = {} if figures is None else {
            "rate_hz": figures.rate_hz, "min_s": figures.min_s, "max_s": figures.max_s,
            "std_s": figures.std_s, "window": figures.messages,
        }  # fmt: skip
        return json.dumps({"key": key, **values})
    if figures is None:
        return f"{key}: fewer than 2 messages"
    return (
        f"{key}: average rate: {figures.rate_hz:.3f} Hz  min: {figures.min_s:.4f}s  max: {figures.max_s:.4f}s"
        f"  std dev: {figures.std_s:.5f}s  window: {figures.messages}"
    )


def hz(args: argparse.Namespace, out: TextIO | None = None, rates: RateWindow | None = None) -> RateWindow:
    """Measure (into ``rates``, or a new window) until ``--duration``, ``--count`` reports or a signal;
    returns the window."""
    out = sys.stdout if out is None else out
    rates = RateWindow(args.window, args.per_key, args.key) if rates is None else rates
    deadline = Deadline(args.duration)
    sink = SampleQueue(args.queue, keep_bytes=False)
    reports = 0
    reported_total = -1

    def report() -> None:
        nonlocal reported_total
        reported_total = rates.total
        if not rates.arrivals:
            print(f"{args.key}: no messages yet", file=out, flush=True)
        for key, figures in rates.figures().items():
            print(report_line(key, figures, args.json), file=out, flush=True)

    with stop_on_signals() as stop, open_probe_session(args) as session:
        subscriber = session.declare_subscriber(args.key, sink)
        try:
            next_report = time.monotonic() + args.every
            while not stop.is_set() and not deadline.passed() and (not args.count or reports < args.count):
                arrival = sink.take(min(deadline.left(0.1), max(0.0, next_report - time.monotonic())))
                if arrival is not None:
                    rates.add(arrival.key, arrival.arrival_s)
                if time.monotonic() >= next_report:
                    next_report += args.every
                    reports += 1
                    report()
        finally:
            subscriber.undeclare()
    while (arrival := sink.take(0.0)) is not None:  # what arrived before the end counts
        rates.add(arrival.key, arrival.arrival_s)
    if rates.total != reported_total:  # the figures at the end (^C, --duration)
        report()
    return rates


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("hz", help="the rate of a key expression (like ros2 topic hz)")
    add_key_probe_arguments(parser, "reports", queue=4096)
    parser.add_argument("--window", type=int, default=100, help="arrivals the figures are made from")
    parser.add_argument("--every", type=float, default=1.0, help="seconds between reports")
    parser.add_argument("--per-key", action="store_true", help="one line per key under the expression")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    check_key_expr(args.key)
    if args.window < 2:
        raise UsageError(f"--window must be >= 2 (arrivals), got {args.window}")
    check_positive(args.every, "--every")
    check_positive(args.count, "--count", allow_zero=True)
    check_positive(args.duration, "--duration", allow_zero=True)
    check_positive(args.queue, "--queue")
    hz(args)
    return 0
