"""The ONE codec that carries every message of :mod:`common.wire.messages` and :mod:`common.wire.rig` (their
base: :mod:`common.wire.schema`), and their registry (:data:`MESSAGE_TYPES`).

Encoding (schema version :data:`SCHEMA_VERSION`): a message becomes two byte strings,

- ``attachment`` = a msgpack map ``{"v": version, "t": type, "f": {scalar fields}, "a": [[name, dtype,
  shape, nbytes], ...]}`` (the header), and
- ``payload`` = the raw bytes of the message's arrays, concatenated in header order (pixels, crops).

A :class:`~common.wire.messages.Frame` whose ``encoding`` is not ``mono8`` travels with its compressed
bytes (one 1-D uint8 array, ``Frame.COMPRESSED_NAME``) instead of its pixels: :func:`encode` compresses
(:mod:`common.wire.frame_codec`), :func:`decode` decompresses once, after checking the stream's own stated
size against the frame's width and height, so every consumer sees ``pixels`` ``(height, width)`` uint8.

Zenoh carries the header as the sample/query attachment and the raw bytes as the payload, so images
never pass through msgpack. A message without arrays may also travel as the header alone in the payload
(``attachment=None``), which is how error replies travel (``reply_err`` has no attachment).

:func:`decode` validates everything once, at the boundary, and raises :class:`WireError` naming what is
wrong: not msgpack, wrong version, unknown type, unknown or missing field, truncated or oversized payload,
dtype or shape mismatch, NaN/inf, a compressed frame that is corrupt or states another size.
"""

from __future__ import annotations

import math
from typing import Any, TypeVar

import msgpack
import numpy as np
from pydantic import BaseModel, ValidationError

from common.wire import frame_codec
from common.wire.messages import (
    AttitudeEstimate,
    BlockJob,
    BlockResult,
    ErrorReply,
    Frame,
    Health,
    ImuSample,
    PatchJob,
    PatchResult,
    PoseEstimate,
    RangeSample,
    Stats,
    YawEstimate,
)
from common.wire.rig import RigMessage
from common.wire.schema import (
    MAX_FRAME_SIDE_PX,
    MAX_HEADER_BYTES,
    SCHEMA_VERSION,
    WIRE_NP_DTYPES,
    WireError,
    WireModel,
)

M = TypeVar("M", bound=WireModel)
#: every message the codec carries, by the type name in its header
MESSAGE_TYPES: dict[str, type[WireModel]] = {
    cls.__name__: cls
    for cls in (
        Frame,
        ImuSample,
        RangeSample,
        YawEstimate,
        AttitudeEstimate,
        PoseEstimate,
        PatchJob,
        BlockJob,
        PatchResult,
        BlockResult,
        Stats,
        Health,
        ErrorReply,
        RigMessage,
    )
}


def encode(message: WireModel) -> tuple[bytes, bytes]:
    """Return ``(payload, attachment)``: raw array bytes and the msgpack header."""
    name = type(message).__name__
    if MESSAGE_TYPES.get(name) is not type(message):
        raise WireError(f"cannot encode {name}: not a registered message type")
    fields: dict[str, Any] = {}
    for key in type(message).model_fields:
        if key not in message.ARRAYS:
            value = getattr(message, key)
            # a nested model (a job's settings) travels as a map, its enums by value
            fields[key] = value.model_dump(mode="json") if isinstance(value, BaseModel) else value
    descriptors = []
    chunks = []
    for key, arr in _wire_arrays(message):
        descriptors.append([key, arr.dtype.str, list(arr.shape), arr.nbytes])
        chunks.append(arr.tobytes())
    try:
        header = msgpack.packb(
            {"v": SCHEMA_VERSION, "t": name, "f": fields, "a": descriptors}, use_bin_type=True
        )
    except (TypeError, ValueError, OverflowError) as exc:
        raise WireError(f"cannot encode {name}: {exc}") from exc
    return b"".join(chunks), header


def _wire_arrays(message: WireModel) -> list[tuple[str, np.ndarray]]:
    """The arrays ``message`` travels with: its :attr:`~WireModel.ARRAYS`, or a compressed frame's bytes."""
    if isinstance(message, Frame) and message.encoding != "mono8":
        quality = message.quality if message.quality is not None else frame_codec.DEFAULT_JPEG_QUALITY
        data = frame_codec.encode(message.pixels, message.encoding, quality)
        return [(Frame.COMPRESSED_NAME, np.frombuffer(data, np.uint8))]
    return [(key, np.ascontiguousarray(getattr(message, key))) for key in message.ARRAYS]


def encode_header_only(message: WireModel) -> bytes:
    """Encode an array-free message as one byte string (for ``reply_err`` and plain puts)."""
    payload, header = encode(message)
    if payload:
        raise WireError(f"{type(message).__name__} has arrays; it needs payload and attachment")
    return header


def _unpack_header(attachment: bytes) -> dict[str, Any]:
    if len(attachment) > MAX_HEADER_BYTES:
        raise WireError(f"header too large: {len(attachment)} bytes > {MAX_HEADER_BYTES}")
    try:
        header = msgpack.unpackb(attachment, raw=False, strict_map_key=True)
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise WireError(f"header is not valid msgpack ({type(exc).__name__}: {exc})") from None
    if not isinstance(header, dict):
        raise WireError(f"header must be a map, got {type(header).__name__}")
    unknown = set(header) - {"v", "t", "f", "a"}
    if unknown:
        raise WireError(f"header has unknown keys {sorted(map(str, unknown))}")
    if header.get("v") != SCHEMA_VERSION:
        raise WireError(f"wrong schema version {header.get('v')!r}, expected {SCHEMA_VERSION}")
    return header


def decode(payload: bytes | None, attachment: bytes | None, expected: type[M] | None = None) -> M:
    """Decode and validate one message; raise :class:`WireError` naming the problem.

    ``attachment=None`` means the payload is the header alone (array-free messages).
    ``expected`` restricts the type (a subclass such as :class:`BlockJob` is not a :class:`PatchJob`).
    """
    if attachment is None:
        if payload is None:
            raise WireError("empty message: no payload and no attachment")
        attachment, payload = payload, b""
    payload = payload or b""
    header = _unpack_header(attachment)
    name = header.get("t")
    cls = MESSAGE_TYPES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise WireError(f"unknown message type {name!r}")
    if expected is not None and cls is not expected:
        raise WireError(f"expected {expected.__name__}, got {name}")
    fields = header.get("f")
    descriptors = header.get("a")
    if not isinstance(fields, dict) or not isinstance(descriptors, list):
        raise WireError(f"{name}: header fields must be a map and arrays a list")
    values: dict[str, Any] = dict(fields)
    offset = 0
    view = memoryview(payload)
    for item in descriptors:
        if not (isinstance(item, list) and len(item) == 4):
            raise WireError(f"{name}: array descriptor must be [name, dtype, shape, nbytes], got {item!r}")
        key, dtype, shape, nbytes = item
        if key not in cls.ARRAYS and not (cls is Frame and key == Frame.COMPRESSED_NAME):
            raise WireError(f"{name}: unknown array field {key!r}")
        if key in values:
            raise WireError(f"{name}: field {key!r} given twice")
        np_dtype = WIRE_NP_DTYPES.get(dtype) if isinstance(dtype, str) else None
        if np_dtype is None:
            raise WireError(f"{name}.{key}: dtype {dtype!r} not allowed on the wire")
        if not (
            isinstance(shape, list)
            and len(shape) <= 8
            and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape)
        ):
            raise WireError(f"{name}.{key}: bad shape {shape!r}")
        if not isinstance(nbytes, int) or nbytes != math.prod(shape) * np_dtype.itemsize:
            raise WireError(f"{name}.{key}: shape {shape} of {dtype} does not match nbytes {nbytes!r}")
        if offset + nbytes > len(view):
            raise WireError(
                f"{name}.{key}: truncated payload ({len(view)} bytes, arrays need at least {offset + nbytes})"
            )
        values[key] = np.frombuffer(view[offset : offset + nbytes], dtype=np_dtype).reshape(shape)
        offset += nbytes
    if offset != len(view):
        raise WireError(f"{name}: payload has {len(view) - offset} bytes more than its arrays declare")
    if cls is Frame:
        _decompress_frame(values)
    try:
        return cls.model_validate(values)  # type: ignore[return-value]
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(map(str, err['loc'])) or 'message'}: {err['msg']}" for err in exc.errors()[:5]
        )
        raise WireError(f"{name}: {problems}") from None


def _decompress_frame(values: dict[str, Any]) -> None:
    """A compressed frame's ``pixels`` from its bytes (decoded once, here, and checked against its declared
    size before anything is decompressed: :func:`common.wire.frame_codec.decode`); a mono8 frame as it is."""
    encoding = values.get("encoding", "mono8")
    data = values.pop(Frame.COMPRESSED_NAME, None)
    if encoding == "mono8" or encoding not in frame_codec.FRAME_ENCODINGS:
        if data is not None:
            raise WireError(f"Frame: compressed bytes in a frame of encoding {encoding!r}")
        return  # a mono8 frame's pixels (or a bad encoding, which validation names)
    if data is None or "pixels" in values:
        raise WireError(
            f"Frame: a {encoding} frame carries its bytes as {Frame.COMPRESSED_NAME!r}, not pixels"
        )
    try:
        data = Frame.COMPRESSED_SPEC.check(Frame.COMPRESSED_NAME, data)
    except ValueError as exc:
        raise WireError(f"Frame.{exc}") from None
    width, height = values.get("width"), values.get("height")
    for side, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_FRAME_SIDE_PX:
            raise WireError(f"Frame.{side}: must be an integer in 1..{MAX_FRAME_SIDE_PX}, got {value!r}")
    assert isinstance(width, int) and isinstance(height, int)
    values["pixels"] = frame_codec.decode(data.data, encoding, width, height)


def error_reply(kind: str, error: str) -> bytes:
    """The one-string body of an error reply."""
    return encode_header_only(ErrorReply(kind=kind, error=error[:2000]))


def read_error_reply(payload: bytes) -> str:
    """Text of an error reply body (also when it is not a well-formed :class:`ErrorReply`)."""
    try:
        reply = decode(payload, None, ErrorReply)
    except WireError:
        return payload[:200].decode("utf-8", "replace")
    return f"{reply.kind}: {reply.error}"
