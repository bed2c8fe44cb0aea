"""ROS bags through ``rosbags`` (pure Python, no ROS install): ROS 1 ``.bag`` files and ROS 2 bags
(a folder with ``metadata.yaml``, or one ``.mcap`` / ``.db3`` file).

Read: ``sensor_msgs/Image`` (mono8, mono16, bgr8, rgb8; converted to 8-bit grey), ``sensor_msgs/
CompressedImage`` (whatever OpenCV decodes), ``sensor_msgs/Imu``, ``sensor_msgs/Range`` and
``sensor_msgs/CameraInfo`` (the calibration). Stamps are the messages' ``header.stamp`` (the sensor's
time base); the bag's log order is put back in stamp order within a bounded window.

Topics are found by message type; a bag with two topics of one type needs the topic named. Unknown
image encodings, a named topic that is not in the bag, a bag without an image topic, a truncated or
corrupt bag: one :class:`BagError` naming it.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.camera import CameraModel
from common.datasets.calibration import CalibrationError, camera_from_camera_info
from common.datasets.source import in_stamp_order, to_grey_u8
from common.errors import InputError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
IMU = "sensor_msgs/msg/Imu"
RANGE = "sensor_msgs/msg/Range"
INFO = "sensor_msgs/msg/CameraInfo"
#: image encodings converted to grey (others are refused)
ENCODINGS = ("mono8", "mono16", "bgr8", "rgb8")


class BagError(InputError):
    """A bag cannot be replayed: not a bag, truncated, a topic missing, an unsupported encoding."""


@dataclass(frozen=True)
class BagTopics:
    """Which topic carries what (``None`` = absent: no IMU, no range, no calibration)."""

    image: str
    imu: str | None = None
    range: str | None = None
    camera_info: str | None = None


@dataclass(frozen=True)
class Bag:
    """An opened (checked) bag: its path, chosen topics, message counts and the camera calibration."""

    path: Path
    topics: BagTopics
    counts: dict[str, int] = field(default_factory=dict)
    camera_info: CameraModel | None = None
    #: size of the first image (every frame must have it)
    width: int = 0
    height: int = 0

    def measurements(self, on_skip: Callable[[str, str], None] | None = None) -> Iterator[Measurement]:
        """Frames, IMU and range samples in stamp order. A sample that cannot be a measurement (a range
        outside its min/max, a non-finite IMU value) is skipped and reported to ``on_skip(kind, why)``."""
        return in_stamp_order(self._raw(on_skip))

    def _raw(self, on_skip: Callable[[str, str], None] | None) -> Iterator[tuple[float, Measurement]]:
        wanted = {t for t in (self.topics.image, self.topics.imu, self.topics.range) if t}
        with _BagReader(self.path) as reader:
            connections = [c for c in reader.connections if c.topic in wanted]
            for connection, _log_ns, raw in _guard(self.path, reader.messages(connections=connections)):
                msg = _deserialize(self.path, reader, raw, connection)
                stamp_s = stamp_of(msg)
                if connection.topic == self.topics.image:
                    yield (
                        stamp_s,
                        FrameMeasurement(stamp_s, image_of(msg, connection.msgtype, connection.topic)),
                    )
                elif connection.topic == self.topics.imu:
                    g, a = msg.angular_velocity, msg.linear_acceleration
                    gyro, accel = np.array([g.x, g.y, g.z]), np.array([a.x, a.y, a.z])
                    if np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel)):
                        yield stamp_s, ImuMeasurement(stamp_s, gyro, accel)
                    elif on_skip:
                        on_skip("imu", "non-finite IMU sample")
                else:
                    value = float(msg.range)
                    if np.isfinite(value) and value > 0 and msg.min_range <= value <= msg.max_range:
                        yield stamp_s, RangeMeasurement(stamp_s, value)
                    elif on_skip:
                        on_skip("range", f"range {value} outside [{msg.min_range}, {msg.max_range}]")


def stamp_of(msg: Any) -> float:
    """``header.stamp`` in seconds (ROS 2 ``sec/nanosec``, ROS 1 ``sec/nsec``)."""
    stamp = msg.header.stamp
    nanos = stamp.nanosec if hasattr(stamp, "nanosec") else stamp.nsec
    return (int(stamp.sec) * 1_000_000_000 + int(nanos)) / 1e9  # one rounding: ns / 1e9


def image_of(msg: Any, msgtype: str, topic: str) -> np.ndarray:
    """8-bit grey pixels of an Image or CompressedImage message; BagError if it cannot be converted."""
    if msgtype == COMPRESSED:
        data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
        if image is None:
            raise BagError(f"{topic}: compressed image (format {msg.format!r}) cannot be decoded")
        return image
    encoding = str(msg.encoding).lower()
    if encoding not in ENCODINGS:
        raise BagError(f"{topic}: image encoding {msg.encoding!r} is not supported ({', '.join(ENCODINGS)})")
    channels, depth = {"mono8": (1, 1), "mono16": (1, 2), "bgr8": (3, 1), "rgb8": (3, 1)}[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or step < w * channels * depth or data.size < h * step:
        raise BagError(f"{topic}: image {w}x{h} step {step} does not fit its {data.size} bytes")
    rows = data[: h * step].reshape(h, step)[:, : w * channels * depth]
    if depth == 2:
        pixels = rows.copy().view(">u2" if msg.is_bigendian else "<u2").reshape(h, w)
    else:
        pixels = rows.reshape(h, w, channels) if channels == 3 else rows
    return to_grey_u8(pixels, encoding, topic)


def camera_info_of(msg: Any, topic: str = "camera_info") -> CameraModel:
    """A ``sensor_msgs/CameraInfo`` as the project's :class:`~common.camera.CameraModel` (``K`` row-major,
    ``D`` in ROS order; ``plumb_bob`` = radtan, ``equidistant`` = fisheye)."""
    k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, dtype=np.float64)
    d = np.asarray(msg.d if hasattr(msg, "d") else msg.D, dtype=np.float64)
    try:
        return camera_from_camera_info(
            int(msg.width), int(msg.height), str(msg.distortion_model) or "plumb_bob", d.tolist(), k.tolist()
        )
    except CalibrationError as exc:
        raise BagError(f"{topic}: camera_info is not a usable calibration ({exc})") from None


#: what rosbags and the storage layers raise for a file that is not a (whole) bag
_READ_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    ValueError,
    KeyError,
    IndexError,
    EOFError,
    struct.error,
    sqlite3.DatabaseError,
    AssertionError,
)


def _rosbags_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error

    return (AnyReaderError, Reader1Error, Reader2Error, *_READ_ERRORS)


class _BagReader:
    """``AnyReader`` on one bag, its errors turned into BagError."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __enter__(self) -> Any:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag")
        try:
            self.reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self.reader.open()
        except _rosbags_errors() as exc:
            raise BagError(f"{self.path}: not a readable ROS 1 or ROS 2 bag ({_why(exc)})") from None
        return self.reader

    def __exit__(self, *exc: object) -> None:
        try:
            self.reader.close()
        except _rosbags_errors():
            pass


def _why(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:300]


def _guard(path: Path, items: Iterator[Any]) -> Iterator[Any]:
    """Iterate ``items``; a read error becomes BagError (truncated or corrupt bag)."""
    try:
        yield from items
    except _rosbags_errors() as exc:
        raise BagError(f"{path}: truncated or corrupt bag ({_why(exc)})") from None


def _deserialize(path: Path, reader: Any, raw: bytes, connection: Any) -> Any:
    try:
        return reader.deserialize(raw, connection.msgtype)
    except _rosbags_errors() as exc:
        raise BagError(f"{path}: {connection.topic}: message cannot be decoded ({_why(exc)})") from None


def _pick(
    by_type: dict[str, list[str]],
    types: tuple[str, ...],
    chosen: str | None,
    what: str,
    available: list[str],
    required: bool,
) -> str | None:
    candidates = [t for msgtype in types for t in by_type.get(msgtype, [])]
    if chosen is not None:
        if chosen not in available:
            raise BagError(
                f"{what} topic {chosen!r} is not in the bag (topics: {', '.join(available) or 'none'})"
            )
        if chosen not in candidates:
            raise BagError(f"{what} topic {chosen!r} does not carry {' or '.join(types)}")
        return chosen
    if len(candidates) > 1:
        raise BagError(f"several {what} topics ({', '.join(candidates)}): name one with --{what}-topic")
    if not candidates and required:
        raise BagError(
            f"no {what} topic ({' or '.join(types)}) in the bag (topics: {', '.join(available) or 'none'})"
        )
    return candidates[0] if candidates else None


def open_bag(
    path: Path,
    image_topic: str | None = None,
    imu_topic: str | None = None,
    range_topic: str | None = None,
    camera_info_topic: str | None = None,
) -> Bag:
    """Open and check a bag: choose topics, read the first CameraInfo, count messages."""
    path = Path(path)
    with _BagReader(path) as reader:
        available = sorted({c.topic for c in reader.connections})
        by_type: dict[str, list[str]] = {}
        for c in reader.connections:
            if c.topic not in by_type.setdefault(c.msgtype, []):
                by_type[c.msgtype].append(c.topic)
        image = _pick(by_type, (IMAGE, COMPRESSED), image_topic, "image", available, required=True)
        topics = BagTopics(
            image=str(image),
            imu=_pick(by_type, (IMU,), imu_topic, "imu", available, required=imu_topic is not None),
            range=_pick(by_type, (RANGE,), range_topic, "range", available, required=range_topic is not None),
            camera_info=_pick(
                by_type,
                (INFO,),
                camera_info_topic,
                "camera-info",
                available,
                required=camera_info_topic is not None,
            ),
        )
        counts: dict[str, int] = {}
        for c in reader.connections:
            counts[c.topic] = counts.get(c.topic, 0) + int(c.msgcount)
        if not counts.get(topics.image):
            raise BagError(f"{path}: image topic {topics.image} has no messages")
        info = None
        if topics.camera_info is not None:
            connections = [c for c in reader.connections if c.topic == topics.camera_info]
            for connection, _t, raw in _guard(path, reader.messages(connections=connections)):
                info = camera_info_of(_deserialize(path, reader, raw, connection), connection.topic)
                break
        # the first image is decoded now: an unsupported encoding is refused before anything is published
        connections = [c for c in reader.connections if c.topic == topics.image]
        first = None
        for connection, _t, raw in _guard(path, reader.messages(connections=connections)):
            msg = _deserialize(path, reader, raw, connection)
            first = image_of(msg, connection.msgtype, connection.topic)
            break
    if first is None:
        raise BagError(f"{path}: image topic {topics.image} has no readable message")
    if info is not None and (info.width, info.height) != (first.shape[1], first.shape[0]):
        raise BagError(
            f"{topics.camera_info}: calibration is {info.width}x{info.height}, the images "
            f"{first.shape[1]}x{first.shape[0]}"
        )
    return Bag(path, topics, counts, info, first.shape[1], first.shape[0])
