"""capataz recordings: MCAP files of the wire messages (``capataz record``), and reading them back
(``capataz camera --mcap``).

One MCAP channel per Zenoh key. Frames are ``foxglove.RawImage`` (protobuf, the Foxglove well-known
schema: Foxglove's Image panel shows them as they are); every other message is JSON with a JSON Schema made
from its pydantic model (arrays as nested lists; nothing is lost: covariances, timings, shares). Each pose
key also gets a ``foxglove.PoseInFrame`` channel ``<key>/in_frame`` (frame ``world``) for Foxglove's 3D panel.
A message's log time is when the recorder received it; its publish time the sender's Zenoh timestamp
when the sample carries one (else the log time); the sensor stamp stays in the message.

Chunks are compressed (:class:`Compression`, zstd by default; MCAP readers, Foxglove included, read all
three); the measured size and cost of each are in docs/operations.md.
"""

from __future__ import annotations

import json
import struct
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

import numpy as np
from pydantic.json_schema import GenerateJsonSchema

from common.datasets.source import in_stamp_order
from common.errors import InputError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement
from common.wire.messages import Frame, ImuSample, PoseEstimate, RangeSample
from common.wire.schema import WireModel

#: suffix of the derived PoseInFrame channel of a pose key
IN_FRAME = "/in_frame"


class Compression(StrEnum):
    """MCAP chunk compression of a recording (``capataz record --compression``)."""

    NONE = "none"
    LZ4 = "lz4"
    ZSTD = "zstd"


class RecordingError(InputError):
    """A recording cannot be written or read (not an MCAP file, truncated, no such UAV stream)."""


class _ArraysAsLists(GenerateJsonSchema):
    def is_instance_schema(self, schema: Any) -> dict[str, Any]:
        return {"type": "array", "items": {}}


def json_schema(cls: type[WireModel]) -> dict[str, Any]:
    """JSON Schema of a wire message; array fields are nested lists of numbers (dtype and shape noted)."""
    schema = cls.model_json_schema(schema_generator=_ArraysAsLists)
    schema["title"] = f"capataz.{cls.__name__}"
    for name, spec in cls.ARRAYS.items():
        shape = ["n" if n is None else n for n in spec.shape]
        schema["properties"][name] = {"type": "array", "description": f"{spec.dtype} array of shape {shape}"}
    return schema


def to_json(message: WireModel) -> bytes:
    """A wire message as JSON (arrays as lists; ``_type`` names the message type)."""
    fields = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in message}
    return json.dumps({"_type": type(message).__name__, **fields}).encode()


def from_json(data: bytes, cls: type[WireModel]) -> WireModel:
    fields = json.loads(data)
    fields.pop("_type", None)
    return cls.model_validate(fields)


def _timestamp(stamp_s: float) -> Any:
    from foxglove.messages import Timestamp

    ns = max(0, round(stamp_s * 1e9))
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def raw_image(frame: Frame) -> bytes:
    """A frame as an encoded ``foxglove.RawImage``."""
    from foxglove.messages import RawImage

    encoded: bytes = RawImage(
        timestamp=_timestamp(frame.stamp_s),
        frame_id=frame.frame_id,
        width=frame.width,
        height=frame.height,
        encoding="mono8",
        step=frame.width,
        data=np.ascontiguousarray(frame.pixels).tobytes(),
    ).encode()
    return encoded


def pose_in_frame(pose: PoseEstimate) -> bytes:
    """A pose as an encoded ``foxglove.PoseInFrame`` in frame ``world``."""
    from foxglove.messages import Pose, PoseInFrame, Quaternion, Vector3

    p, q = pose.p_world_body_m, pose.q_world_body
    encoded: bytes = PoseInFrame(
        timestamp=_timestamp(pose.stamp_s),
        frame_id=pose.frame_id,
        pose=Pose(
            position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            orientation=Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
        ),
    ).encode()
    return encoded


class RecordingWriter:
    """Writes wire messages into an MCAP file, one channel per key (thread-safe; ``close`` finishes it),
    its chunks compressed with ``compression``."""

    def __init__(self, path: Path, compression: Compression = Compression.ZSTD) -> None:
        from mcap.writer import CompressionType, Writer

        kind = {
            Compression.NONE: CompressionType.NONE,
            Compression.LZ4: CompressionType.LZ4,
            Compression.ZSTD: CompressionType.ZSTD,
        }[Compression(compression)]

        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot be written ({exc})") from None
        self._writer = Writer(self._file, compression=kind)
        self._writer.start(profile="", library="capataz")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._lock = threading.Lock()
        self.messages = 0
        self.closed = False

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        if name not in self._schemas:
            self._schemas[name] = self._writer.register_schema(name=name, encoding=encoding, data=data)
        return self._schemas[name]

    def _channel(self, topic: str, message: WireModel, foxglove_pose: bool = False) -> int:
        if topic in self._channels:
            return self._channels[topic]
        if isinstance(message, Frame) or foxglove_pose:
            from foxglove.messages import PoseInFrame, RawImage

            schema = (RawImage if isinstance(message, Frame) else PoseInFrame).get_schema()
            schema_id = self._schema(schema.name, schema.encoding, bytes(schema.data))
            encoding = "protobuf"
        else:
            cls = type(message)
            schema_id = self._schema(
                f"capataz.{cls.__name__}", "jsonschema", json.dumps(json_schema(cls)).encode()
            )
            encoding = "json"
        metadata = {"capataz_type": type(message).__name__}
        self._channels[topic] = self._writer.register_channel(topic, encoding, schema_id, metadata)
        return self._channels[topic]

    def _add(self, channel: int, log_ns: int, data: bytes, publish_ns: int) -> None:
        self._sequence[channel] = self._sequence.get(channel, -1) + 1
        self._writer.add_message(channel, log_ns, data, publish_ns, self._sequence[channel] & 0xFFFFFFFF)

    def write(
        self, key: str, message: WireModel, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        publish_ns = log_time_ns if publish_time_ns is None else publish_time_ns
        data = raw_image(message) if isinstance(message, Frame) else to_json(message)
        with self._lock:
            if self.closed:
                return
            self._add(self._channel(key, message), log_time_ns, data, publish_ns)
            if isinstance(message, PoseEstimate):
                channel = self._channel(key + IN_FRAME, message, foxglove_pose=True)
                self._add(channel, log_time_ns, pose_in_frame(message), publish_ns)
            self.messages += 1

    def close(self) -> None:
        with self._lock:
            if not self.closed:
                self.closed = True
                finish: Callable[[], object] = self._writer.finish  # mcap's writer is untyped
                finish()
                self._file.close()


def _protobuf_class(schema: Any) -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in files.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


@dataclass(frozen=True)
class Recording:
    """An opened capataz recording: the UAV stream replayed and its frame count and size."""

    path: Path
    uav: str
    frames: int
    width: int
    height: int
    topics: tuple[str, ...]

    def measurements(self) -> Iterator[Measurement]:
        """Frames, IMU and range samples of the UAV in stamp order."""
        return in_stamp_order(self._raw())

    def _raw(self) -> Iterator[tuple[float, Measurement]]:
        camera, imu, rng = (f"capataz/uav/{self.uav}/{t}" for t in ("camera", "imu", "range"))
        with _McapFile(self.path) as reader:
            raw_cls = None
            for schema, channel, message in _guard(
                self.path, reader.iter_messages(topics=[camera, imu, rng])
            ):
                if channel.topic == camera:
                    raw_cls = raw_cls or _protobuf_class(schema)
                    image = raw_cls.FromString(message.data)
                    stamp = (image.timestamp.seconds * 1_000_000_000 + image.timestamp.nanos) / 1e9
                    if image.encoding != "mono8" or len(image.data) != image.width * image.height:
                        raise RecordingError(
                            f"{self.path}: {camera}: not a mono8 {image.width}x{image.height} image"
                        )
                    pixels = np.frombuffer(image.data, np.uint8).reshape(image.height, image.width)
                    yield stamp, FrameMeasurement(stamp, pixels)
                elif channel.topic == imu:
                    s = from_json(message.data, ImuSample)
                    assert isinstance(s, ImuSample)
                    yield s.stamp_s, ImuMeasurement(s.stamp_s, s.gyro_rad_s, s.accel_m_s2)
                else:
                    r = from_json(message.data, RangeSample)
                    assert isinstance(r, RangeSample)
                    yield r.stamp_s, RangeMeasurement(r.stamp_s, r.range_m)


class _McapFile:
    def __init__(self, path: Path) -> None:
        self.path = path

    def __enter__(self) -> Any:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader

        try:
            self.file = self.path.open("rb")
            return make_reader(self.file)
        except (OSError, ValueError, McapError, struct.error, EOFError) as exc:
            raise RecordingError(f"{self.path}: not a readable MCAP file ({exc})") from None

    def __exit__(self, *exc: object) -> None:
        self.file.close()


def _guard(path: Path, items: Iterator[Any]) -> Iterator[Any]:
    from mcap.exceptions import McapError

    try:
        yield from items
    except (McapError, ValueError, KeyError, EOFError, OSError, struct.error) as exc:
        raise RecordingError(
            f"{path}: truncated or corrupt recording ({type(exc).__name__}: {exc})"
        ) from None


def open_recording(path: Path, uav: str | None = None) -> Recording:
    """Open a recording and choose its UAV stream (``uav``, or the only one recorded)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording")
    with _McapFile(path) as reader:
        try:
            summary = reader.get_summary()
        except Exception as exc:  # the mcap reader raises several unrelated types for a broken file
            raise RecordingError(f"{path}: not a readable MCAP file ({type(exc).__name__}: {exc})") from None
        if summary is None:
            raise RecordingError(f"{path}: MCAP file without a summary (not finished?)")
        channels = {c.topic: c for c in summary.channels.values()}
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        uavs = sorted(
            {t.split("/")[2] for t in channels if t.startswith("capataz/uav/") and t.endswith("/camera")}
        )
        chosen = uav if uav in uavs else (uavs[0] if len(uavs) == 1 else None)
        if chosen is None:
            raise RecordingError(
                f"{path}: no camera stream of {uav!r} (recorded: {', '.join(uavs) or 'none'})"
            )
        camera = channels[f"capataz/uav/{chosen}/camera"]
        frames = int(counts.get(camera.id, 0))
        width = height = 0
        for schema, _channel, message in _guard(path, reader.iter_messages(topics=[camera.topic])):
            image = _protobuf_class(schema).FromString(message.data)
            width, height = int(image.width), int(image.height)
            break
    if frames < 1 or not width:
        raise RecordingError(f"{path}: the camera stream of {chosen} has no frames")
    return Recording(path, chosen, frames, width, height, tuple(sorted(channels)))
