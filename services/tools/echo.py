"""``capataz echo KEY``: print each message on a key expression, one line each, like ``ros2 topic echo``.

Each sample is decoded with the one codec (:mod:`common.wire.codec`); a line is ``KEY TYPE {fields}``
(arrays as ``<dtype shape>`` unless small), or with ``--json`` one JSON object per line for scripts. A
sample that is not a capataz message is reported on stderr and counted, not printed as one. Bounded:
``--count`` messages or ``--duration`` seconds; SIGINT/SIGTERM end it cleanly (exit 0).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from typing import Any, TextIO

from services.tools.probe import (
    Arrival,
    Deadline,
    SampleQueue,
    add_key_probe_arguments,
    check_key_expr,
    check_positive,
    decoded,
    open_probe_session,
    stop_on_signals,
    summary_fields,
)

logger = logging.getLogger(__name__)


def echo_line(arrival: Arrival, as_json: bool) -> tuple[str, bool]:
    """The line printed for one arrival and whether it carried a message."""
    message, why = decoded(arrival)
    if message is None:
        return f"{arrival.key}: not a capataz message ({why})", False
    fields = summary_fields(message)
    if as_json:
        return json.dumps({"key": arrival.key, "type": type(message).__name__, "fields": fields}), True
    return f"{arrival.key} {type(message).__name__} {json.dumps(fields, separators=(',', ':'))}", True


def echo(args: argparse.Namespace, out: TextIO | None = None) -> dict[str, int]:
    """Print messages until ``--count``, ``--duration`` or a signal; returns what was printed and refused."""
    out = sys.stdout if out is None else out
    printed = malformed = 0
    deadline = Deadline(args.duration)
    sink = SampleQueue(args.queue)
    with stop_on_signals() as stop, open_probe_session(args) as session:
        subscriber = session.declare_subscriber(args.key, sink)
        try:
            while not stop.is_set() and not deadline.passed() and (not args.count or printed < args.count):
                arrival = sink.take(deadline.left(0.1))
                if arrival is None:
                    continue
                line, ok = echo_line(arrival, args.json)
                if ok:
                    printed += 1
                    print(line, file=out, flush=True)
                else:
                    malformed += 1
                    print(line, file=sys.stderr, flush=True)
        finally:
            subscriber.undeclare()
    return {"printed": printed, "malformed": malformed, "dropped": sink.dropped}


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("echo", help="print each message on a key expression (ros2 topic echo)")
    add_key_probe_arguments(parser, "messages", queue=64)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    check_key_expr(args.key)
    check_positive(args.count, "--count", allow_zero=True)
    check_positive(args.duration, "--duration", allow_zero=True)
    check_positive(args.queue, "--queue")
    result = echo(args)
    if result["dropped"] or result["malformed"]:
        logger.warning("echo: %d not capataz messages, %d dropped (queue full)", result["malformed"],
                       result["dropped"])  # fmt: skip
    return 0
