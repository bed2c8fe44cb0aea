"""``capataz record --out FILE.mcap``: subscribes to ``capataz/**`` and writes each key as an MCAP channel
(frames as ``foxglove.RawImage``, other messages as JSON with their JSON Schema; log time = receipt, publish
time = the sample's Zenoh timestamp when it has one). ``capataz camera --mcap FILE`` replays a recording.

The subscriber callback only hands the raw sample to a bounded queue; one thread decodes (a malformed
sample is counted, not recorded) and writes. A full queue drops the sample and counts it
(``dropped_full``): recording never slows the deployment down. SIGTERM finishes the file (exit 0).
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path
from typing import Any

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common import keys
from common.datasets.recording import RecordingWriter
from common.messages import WireError, WireModel, decode
from services.runtime.transport import (
    ServiceRuntime,
    TransportSettings,
    WorkQueue,
    add_transport_arguments,
    transport_from_args,
    zbytes,
)

logger = logging.getLogger(__name__)


class RecordSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    out: Path
    #: key expression recorded
    key_expr: str = keys.ALL
    #: samples waiting to be written at most (a 752x480 frame is 361 kB)
    queue: int = Field(default=256, ge=1)
    #: stop after this long (0 = until SIGTERM / ^C)
    duration_s: float = Field(default=0.0, ge=0.0)


_Item = tuple[str, bytes | None, bytes | None, int, int | None]


class RecordService(ServiceRuntime):
    role = keys.Role.RECORDER

    def __init__(
        self, node: str, index: int, transport: TransportSettings, settings: RecordSettings,
        stats_period_s: float = 1.0,
    ) -> None:  # fmt: skip
        super().__init__(node, index, transport, stats_period_s)
        self.settings = settings
        self.writer = RecordingWriter(settings.out)
        self._queue: WorkQueue[_Item] = WorkQueue(settings.queue)
        self._entities: list[Any] = []

    def start(self, session: zenoh.Session) -> None:
        self._entities.append(session.declare_subscriber(self.settings.key_expr, self._on_sample))
        self.spawn(self._write_loop, "write")
        if self.settings.duration_s:
            self.spawn(self._stop_after, "duration")

    def stop(self) -> None:
        self.undeclare_all(self._entities)
        self._drain()
        self.writer.close()
        logger.info("recorded %d messages into %s", self.writer.messages, self.settings.out)

    def queue_depths(self) -> dict[str, int]:
        return {"write": self._queue.depth()}

    def _on_sample(self, sample: zenoh.Sample) -> None:
        log_ns = time.time_ns()
        stamp = sample.timestamp
        publish_ns = int(stamp.get_time().timestamp() * 1e9) if stamp is not None else None
        item = (str(sample.key_expr), zbytes(sample.payload), zbytes(sample.attachment), log_ns, publish_ns)
        if not self._queue.offer(item):
            self.counters.inc("dropped_full")

    def _write(self, item: _Item) -> None:
        key, payload, attachment, log_ns, publish_ns = item
        try:
            message: WireModel = decode(payload, attachment)
        except WireError as exc:
            self.count_error("malformed", f"not recorded: bad message on {key}", exc)
            return
        self.writer.write(key, message, log_ns, publish_ns)
        self.counters.inc("recorded")

    def _write_loop(self) -> None:
        while not self.stop_event.is_set():
            item = self._queue.take(0.1)
            if item is not None:
                self._write(item)

    def _drain(self) -> None:
        for item in self._queue.drain():
            self._write(item)

    def _stop_after(self) -> None:
        if not self.stop_event.wait(self.settings.duration_s):
            self.request_stop()


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("record", help="record every capataz/** message into an MCAP file")
    add_transport_arguments(parser, node_default="recorder")
    parser.add_argument("--out", type=Path, default=Path("out/capataz.mcap"), help="MCAP file written")
    parser.add_argument("--key", default=keys.ALL, help="key expression recorded (default capataz/**)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0 = ^C)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    settings = RecordSettings(out=args.out, key_expr=args.key, duration_s=args.duration)
    return RecordService(args.node, args.index, transport_from_args(args), settings, args.stats_period).run()
