"""``capataz record --out FILE.mcap``: subscribes to ``capataz/**`` and writes each key as an MCAP channel
(frames as ``foxglove.RawImage``, other messages as JSON with their JSON Schema; log time = receipt, publish
time = the sample's Zenoh timestamp when it has one), chunks compressed with zstd unless ``--compression``
says otherwise (``none``, ``lz4``). ``capataz camera --mcap FILE`` replays a recording.

The subscriber callback only hands the raw sample to a bounded queue; one thread decodes (a malformed
sample is counted, not recorded) and writes. A full queue (65536 samples or 512 MB) drops the sample and
counts it (``dropped_full``): recording never slows the deployment down. SIGTERM finishes the file (exit 0).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common.members import Role
from common.recordings.mcap import Compression, RecordingWriter
from common.wire import keys
from common.wire.schema import WireModel
from services.runtime.cli import add_transport_arguments, transport_from_args
from services.runtime.tap import KeyTap
from services.runtime.transport import TransportSettings

logger = logging.getLogger(__name__)


class RecordSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    out: Path
    #: key expression recorded
    key_expr: str = keys.ALL
    #: samples waiting to be written at most, and their bytes (a 752x480 frame is 361 kB, an IMU sample
    #: about 150 B): a writer starved on a busy host catches up instead of losing what it fell behind on
    #: (256 samples lost frames: 2 of 20 in one run of the suite on a loaded host, at 400 IMU samples/s)
    queue: int = Field(default=65536, ge=1)
    queue_mb: int = Field(default=512, ge=1)
    #: stop after this long (0 = until SIGTERM / ^C)
    duration_s: float = Field(default=0.0, ge=0.0)
    #: MCAP chunk compression; zstd made a real camera's video 4x smaller for under 2 % of a core at 20 fps
    #: (measured sizes and costs: docs/operations.md)
    compression: Compression = Compression.ZSTD


class RecordService(KeyTap):
    role = Role.RECORDER

    def __init__(
        self, node: str, index: int, transport: TransportSettings, settings: RecordSettings,
        stats_period_s: float = 1.0,
    ) -> None:  # fmt: skip
        super().__init__(node, index, transport, settings.queue, stats_period_s, settings.queue_mb << 20)
        self.settings = settings
        self.writer = RecordingWriter(settings.out, settings.compression)

    def tap_keys(self) -> tuple[str, ...]:
        return (self.settings.key_expr,)

    def start(self, session: zenoh.Session) -> None:
        super().start(session)
        if self.settings.duration_s:
            self.spawn(self._stop_after, "duration")

    def stop(self) -> None:
        super().stop()
        self.drain()
        self.writer.close()
        logger.info("recorded %d messages into %s", self.writer.messages, self.settings.out)

    def handle(self, key: str, message: WireModel, log_ns: int, publish_ns: int | None) -> None:
        self.writer.write(key, message, log_ns, publish_ns)
        self.counters.inc("recorded")

    def _stop_after(self) -> None:
        if not self.stop_event.wait(self.settings.duration_s):
            self.request_stop()


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("record", help="record every capataz/** message into an MCAP file")
    add_transport_arguments(parser, node_default="recorder")
    parser.add_argument("--out", type=Path, default=Path("out/capataz.mcap"), help="MCAP file written")
    parser.add_argument("--key", default=keys.ALL, help="key expression recorded (default capataz/**)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0 = ^C)")
    parser.add_argument(
        "--compression",
        choices=[c.value for c in Compression],
        default=Compression.ZSTD.value,
        help="MCAP chunk compression",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    settings = RecordSettings(
        out=args.out, key_expr=args.key, duration_s=args.duration, compression=Compression(args.compression)
    )
    return RecordService(args.node, args.index, transport_from_args(args), settings, args.stats_period).run()
