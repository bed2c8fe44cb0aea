"""Every message on the wire, and the ONE codec that carries them.

Encoding (schema version :data:`SCHEMA_VERSION`): a message becomes two byte strings,

- ``attachment`` = a msgpack map ``{"v": version, "t": type, "f": {scalar fields}, "a": [[name, dtype,
  shape, nbytes], ...]}`` (the header), and
- ``payload`` = the raw bytes of the message's arrays, concatenated in header order (pixels, crops).

Zenoh carries the header as the sample/query attachment and the raw bytes as the payload, so images
never pass through msgpack. A message without arrays may also travel as the header alone in the payload
(``attachment=None``), which is how error replies travel (``reply_err`` has no attachment).

:func:`decode` validates everything once, at the boundary, and raises :class:`WireError` naming what is
wrong: not msgpack, wrong version, unknown type, unknown or missing field, truncated or oversized payload,
dtype or shape mismatch, NaN/inf.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, TypeVar

import msgpack
import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StringConstraints,
    ValidationError,
    model_validator,
)

from common.errors import CapatazError, InputError
from common.provenance import Provenance
from common.yaw.settings import FftBackend, FitModel, YawSettings

#: Bump when a field changes meaning; decoders reject other versions.
SCHEMA_VERSION = 1
#: Array dtypes allowed on the wire (little-endian, fixed size).
WIRE_DTYPES: frozenset[str] = frozenset(
    {"|u1", "|b1", "<i4", "<i8", "<u4", "<f4", "<f8", "<c8", "<c16"},
)
#: Parsed wire dtypes (a dtype string parsed for every array of every message costs more than the check).
WIRE_NP_DTYPES: dict[str, np.dtype[Any]] = {name: np.dtype(name) for name in WIRE_DTYPES}
#: Largest header accepted (bytes); arrays travel in the payload, so headers are small.
MAX_HEADER_BYTES = 1 << 20
#: Wire bounds: every count and size a sender chooses is bounded here, at the boundary.
MAX_NAME_CHARS = 64  # UAV ids, stream names
MAX_SEQ = (1 << 63) - 1  # msgpack's signed range
MAX_FRAME_SIDE_PX = 8192
MAX_JOB_PATCHES = 4096
MAX_CROP_SIDE_PX = 512
MAX_JOB_PIXELS = 1 << 24  # crops + previous crops of one job (16 MB)


class WireError(CapatazError):
    """A message could not be encoded or decoded (the text names what is wrong)."""


@dataclass(frozen=True)
class ArraySpec:
    """What an array field must look like: dtype and shape (``None`` = any length on that axis)."""

    dtype: str
    shape: tuple[int | None, ...]
    finite: bool = True

    def __post_init__(self) -> None:
        # resolved once: this check runs for every array of every decoded message
        object.__setattr__(self, "_np_dtype", np.dtype(self.dtype))
        fixed = tuple((axis, n) for axis, n in enumerate(self.shape) if n is not None)
        object.__setattr__(self, "_fixed", fixed)
        object.__setattr__(self, "_check_finite", self.finite and np.dtype(self.dtype).kind in "fc")

    def check(self, name: str, value: Any) -> np.ndarray:
        want: np.dtype[Any] = self._np_dtype  # type: ignore[attr-defined]
        if not isinstance(value, np.ndarray):
            try:
                value = np.asarray(value, dtype=want)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{name}: cannot convert to {self.dtype} array: {exc}") from exc
        if value.dtype != want:
            if value.dtype.kind in "fciub" and np.can_cast(value.dtype, want, casting="same_kind"):
                value = value.astype(want)
            else:
                raise ValueError(f"{name}: expected dtype {self.dtype}, got {value.dtype.str}")
        shape = value.shape
        if len(shape) != len(self.shape) or any(shape[axis] != n for axis, n in self._fixed):  # type: ignore[attr-defined]
            pattern = tuple("n" if s is None else s for s in self.shape)
            raise ValueError(f"{name}: expected shape {pattern}, got {value.shape}")
        if self._check_finite and value.size and not np.isfinite(value).all():  # type: ignore[attr-defined]
            raise ValueError(f"{name}: contains NaN or inf")
        return np.asarray(value)  # the array itself (typed)


class WireModel(BaseModel):
    """Base of every message: frozen, no unknown fields, numpy arrays for :attr:`ARRAYS`."""

    # allow_inf_nan=False: pydantic-core rejects NaN/inf in float fields and dict[str, float] values itself
    model_config = ConfigDict(frozen=True, extra="forbid", arbitrary_types_allowed=True, allow_inf_nan=False)
    #: field name -> spec; these fields travel as raw bytes in the payload.
    ARRAYS: ClassVar[dict[str, ArraySpec]] = {}

    @model_validator(mode="before")
    @classmethod
    def _check_arrays(cls, data: Any) -> Any:
        if isinstance(data, dict):
            data = dict(data)
            for name, spec in cls.ARRAYS.items():
                if name in data:
                    try:
                        data[name] = spec.check(name, data[name])
                    except ValueError as exc:
                        raise ValueError(str(exc)) from None
        return data


Uav = Annotated[str, StringConstraints(min_length=1, max_length=MAX_NAME_CHARS)]
#: Frames of reference (``frame_id``; README "Keys and frames", ROS REP 103): ``world`` (ENU, z up),
#: ``body`` (FLU: x forward, y left, z up), ``camera`` (OpenCV optical: x right, y down, z along the axis).
FRAME_ID_PATTERN = r"^[A-Za-z0-9_./-]{1,64}$"


def frame_id_field(default: str) -> Any:
    """The ``frame_id`` of a message: the frame its data is expressed in (estimates: their parent frame)."""
    return Field(default=default, pattern=FRAME_ID_PATTERN)


# ----------------------------------------------------------------------------------------------- sensors
class UavMessage(WireModel):
    """A message of one UAV's stream: its id, the sequence number and the stamp of what it carries."""

    uav: Uav
    seq: int = Field(ge=0, le=MAX_SEQ, default=0)
    stamp_s: float


class Frame(UavMessage):
    """One camera image of a UAV stream (8-bit grey, row-major ``(height, width)``)."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {"pixels": ArraySpec("|u1", (None, None))}
    seq: int = Field(ge=0, le=MAX_SEQ)  # required
    width: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    height: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    encoding: Literal["mono8"] = "mono8"
    pixels: np.ndarray
    frame_id: str = frame_id_field("camera")

    @model_validator(mode="after")
    def _shape_matches(self) -> Frame:
        if self.pixels.shape != (self.height, self.width):
            raise ValueError(
                f"pixels: shape {self.pixels.shape} != (height, width) = ({self.height}, {self.width})"
            )
        return self


class ImuSample(UavMessage):
    """One IMU reading in the body frame (FLU): angular rate and specific force."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "gyro_rad_s": ArraySpec("<f8", (3,)),
        "accel_m_s2": ArraySpec("<f8", (3,)),
    }
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    frame_id: str = frame_id_field("body")


class RangeSample(UavMessage):
    """One rangefinder reading along body -z."""

    range_m: float = Field(gt=0.0)
    frame_id: str = frame_id_field("body")


# ----------------------------------------------------------------------------------------------- estimates
class YawEstimate(UavMessage):
    """The yaw of one frame, as published by the master on ``capataz/uav/{uav}/yaw``."""

    seq: int = Field(ge=0, le=MAX_SEQ)  # required
    delta_yaw_rad: float
    yaw_rad: float
    inlier_count: int = Field(ge=0)
    patch_count: int = Field(ge=0)
    confidence: float
    low_confidence: bool
    method: str
    #: stage timings of this frame in milliseconds (``total``, ``dispatch``, ``conclude``, ...).
    timings_ms: dict[str, float] = Field(default_factory=dict)
    #: patches computed by each member for this frame (member name -> count; ``self`` = the master).
    members: dict[str, int] = Field(default_factory=dict)
    #: each member's speed as its dispatcher measured it (patches/s; ``foreman>worker`` for the second tier).
    speeds_patches_s: dict[str, float] = Field(default_factory=dict)
    #: frames of this stream dropped so far by the master's bounded frame queue (oldest first), each once.
    dropped_frames: int = Field(ge=0, default=0)
    #: shares re-dispatched in this frame because a member failed.
    redispatched: int = Field(ge=0, default=0)
    #: how ``delta_yaw_rad`` was obtained: measured by the camera, bridged by the gyro, or the held rate.
    provenance: Provenance = Provenance.MEASURED
    #: variance of ``yaw_rad`` (rad^2) and of this frame's ``delta_yaw_rad``; grows fastest while bridging.
    yaw_variance_rad2: float = Field(ge=0.0, default=0.0)
    delta_variance_rad2: float = Field(ge=0.0, default=0.0)
    #: the camera's own delta when it measured one (also when not trusted), else None.
    measured_delta_rad: float | None = None
    #: yaw is the body's rotation about this frame's z axis (from the stream's first frame)
    frame_id: str = frame_id_field("world")


class AttitudeEstimate(UavMessage):
    """Attitude of the body in the world (Hamilton, scalar first) with its 3x3 error-angle covariance."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "q_world_body": ArraySpec("<f8", (4,)),
        "covariance": ArraySpec("<f8", (3, 3)),
    }
    q_world_body: np.ndarray
    covariance: np.ndarray
    frame_id: str = frame_id_field("world")


class PoseEstimate(UavMessage):
    """Position and attitude of the body in the world with a 6x6 covariance [position, error angles]."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "p_world_body_m": ArraySpec("<f8", (3,)),
        "q_world_body": ArraySpec("<f8", (4,)),
        "covariance": ArraySpec("<f8", (6, 6)),
    }
    p_world_body_m: np.ndarray
    q_world_body: np.ndarray
    covariance: np.ndarray
    #: which estimator produced it, e.g. ``"vo"`` or ``"pf"``.
    source: str
    #: the localizer's tracking state: ``tracking`` (the model matches the image), ``searching`` (a few bad
    #: frames: re-searching around the last good pose), ``lost``; None for estimators without one.
    tracking_state: Literal["tracking", "searching", "lost"] | None = None
    frame_id: str = frame_id_field("world")


# ----------------------------------------------------------------------------------------------- work
class YawJobSettings(BaseModel):
    """The yaw settings a job carries (every member measures with the dispatcher's), bounded at the wire.

    The same fields as :class:`~common.yaw.settings.YawSettings` but the lens model (only the central stage
    uses it). Each count and size a member allocates windows and spectra by is bounded here, before any
    allocation; the largest values in use are far below. A decoded value is also a valid ``YawSettings``
    (checked once, at decode): :attr:`yaw_settings` is that object.
    """

    # strict: no bool or string for a number; enums (by value on the wire) stay lax
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False, strict=True)
    patch_size_px: int = Field(ge=8, le=256)
    grid_cols: int = Field(ge=1, le=64)
    grid_rows: int = Field(ge=1, le=64)
    margin_px: int = Field(ge=0, le=4096)
    pyramid_level: int = Field(ge=0, le=4)
    fft_backend: FftBackend = Field(strict=False)
    peak_sigma_px: float = Field(ge=1e-3, le=64.0)
    window_taper: float = Field(ge=0.0, le=1.0)
    overlap_correction: float = Field(ge=0.0, le=8.0)
    min_texture_std: float = Field(ge=0.0, le=255.0)
    min_peak_ratio: float = Field(ge=0.0, le=1e3)
    fit_model: FitModel = Field(strict=False)
    prealigned_fit_model: FitModel = Field(strict=False)
    ransac_threshold_px: float = Field(ge=1e-3, le=1e3)
    ransac_max_iters: int = Field(ge=1, le=10_000)
    min_inliers: int = Field(ge=3, le=4096)
    min_inlier_fraction: float = Field(ge=0.0, le=1.0)
    global_size_px: int = Field(ge=64, le=1024)
    global_angle_bins: int = Field(ge=90, le=4096)
    max_residual_px: float = Field(ge=1e-3, le=1e3)
    refine_min_deg: float = Field(ge=0.0, le=180.0)
    max_yaw_rate_deg_s: float = Field(gt=0.0, le=1e5)
    max_yaw_accel_deg_s2: float = Field(gt=0.0, le=1e7)
    gyro_gate_deg: float = Field(gt=0.0, le=180.0)
    gyro_sigma_deg_s: float = Field(ge=0.0, le=1e3)
    ambiguity_ratio: float = Field(gt=0.0, le=1.0)
    frame_period_s: float = Field(gt=0.0, le=60.0)
    _yaw_settings: YawSettings = PrivateAttr()

    @model_validator(mode="after")
    def _valid_yaw_settings(self) -> YawJobSettings:
        try:
            self._yaw_settings = YawSettings(
                **{name: getattr(self, name) for name in type(self).model_fields}
            )
        except InputError as exc:
            raise ValueError(f"invalid yaw settings: {exc}") from None
        return self

    @classmethod
    def of(cls, settings: YawSettings) -> YawJobSettings:
        """The wire form of ``settings`` (its lens model stays behind: :data:`LOCAL_YAW_SETTINGS`)."""
        values = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
        return cls.model_validate({k: v for k, v in values.items() if k not in LOCAL_YAW_SETTINGS})

    @property
    def yaw_settings(self) -> YawSettings:
        """The core's settings object (no lens model)."""
        return self._yaw_settings


#: Yaw settings only the central stage uses (the lens model): never sent to members.
LOCAL_YAW_SETTINGS = frozenset({"camera"})


class PatchJob(WireModel):
    """Measure the shifts of patches ``indices`` of frame ``seq`` against frame ``prev_seq``.

    ``crops`` are the patches of the new frame; ``prev_crops`` are previous-frame patches for indices the
    member does not hold yet (moved assignment, new member); the member keeps the others' spectra.
    ``settings`` are the dispatcher's yaw settings, so every member measures with the same settings.
    """

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "indices": ArraySpec("<i4", (None,)),
        "crops": ArraySpec("|u1", (None, None, None)),
        "prev_indices": ArraySpec("<i4", (None,)),
        "prev_crops": ArraySpec("|u1", (None, None, None)),
    }
    stream: Uav
    seq: int = Field(ge=0, le=MAX_SEQ)
    prev_seq: int = Field(ge=-1, le=MAX_SEQ)
    settings: YawJobSettings
    indices: np.ndarray
    crops: np.ndarray
    prev_indices: np.ndarray
    prev_crops: np.ndarray
    #: time budget of the request in seconds (a foreman gives its workers part of it).
    budget_s: float = Field(gt=0.0, default=1.0)

    @model_validator(mode="after")
    def _consistent(self) -> PatchJob:
        if self.indices.shape[0] > MAX_JOB_PATCHES:
            raise ValueError(f"indices: {self.indices.shape[0]} patches > {MAX_JOB_PATCHES}")
        side = self.crops.shape[1:]
        if side[0] != side[1] or not 0 < side[0] <= MAX_CROP_SIDE_PX:
            raise ValueError(f"crops: {side} must be square, 1..{MAX_CROP_SIDE_PX} px")
        if self.crops.size + self.prev_crops.size > MAX_JOB_PIXELS:
            raise ValueError(f"crops: {self.crops.size + self.prev_crops.size} pixels > {MAX_JOB_PIXELS}")
        if self.crops.shape[0] != self.indices.shape[0]:
            raise ValueError(f"crops: {self.crops.shape[0]} crops for {self.indices.shape[0]} indices")
        if self.prev_crops.shape[0] != self.prev_indices.shape[0]:
            raise ValueError(
                f"prev_crops: {self.prev_crops.shape[0]} crops for {self.prev_indices.shape[0]} prev_indices"
            )
        if self.prev_indices.size and self.prev_crops.shape[1:] != self.crops.shape[1:]:
            raise ValueError(f"prev_crops: crop shape {self.prev_crops.shape[1:]} != {self.crops.shape[1:]}")
        for name in ("indices", "prev_indices"):
            arr = getattr(self, name)
            if arr.size and not _distinct_non_negative(arr):
                raise ValueError(f"{name}: must be distinct non-negative patch indices")
        if self.prev_indices.size and not np.isin(self.prev_indices, self.indices).all():
            raise ValueError("prev_indices: must be a subset of indices")
        return self


def _distinct_non_negative(indices: np.ndarray) -> bool:
    """True when the 1-D integer ``indices`` are distinct and >= 0 (fast path: strictly ascending)."""
    if indices[0] < 0:
        return False
    if indices.size == 1 or bool((indices[1:] > indices[:-1]).all()):
        return True  # ascending (how dispatchers send them): distinct, and the first is the minimum
    return bool(indices.min() >= 0) and np.unique(indices).size == indices.size


class BlockJob(PatchJob):
    """A master's block of a frame for one foreman (same fields as :class:`PatchJob`)."""


class PatchResult(WireModel):
    """Shifts of frame ``seq`` vs ``prev_seq`` at the patches ``indices`` (order of the job)."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "indices": ArraySpec("<i4", (None,)),
        "shift_px": ArraySpec("<f8", (None, 2), finite=False),
        "confidence": ArraySpec("<f8", (None,), finite=False),
        "peak": ArraySpec("<f8", (None,), finite=False),
        "valid": ArraySpec("|b1", (None,)),
    }
    stream: str
    seq: int = Field(ge=0)
    prev_seq: int = Field(ge=-1)
    member: str
    indices: np.ndarray
    shift_px: np.ndarray
    confidence: np.ndarray
    peak: np.ndarray
    valid: np.ndarray
    #: seconds spent computing (without transport).
    compute_s: float = Field(ge=0.0)
    #: patches computed by each (sub-)member, for reports (a worker: itself; a foreman: its workers).
    members: dict[str, int] = Field(default_factory=dict)
    #: measured speed of each (sub-)member in patches per second.
    speeds: dict[str, float] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _consistent(self) -> PatchResult:
        n = self.indices.shape[0]
        for name in ("shift_px", "confidence", "peak", "valid"):
            if getattr(self, name).shape[0] != n:
                raise ValueError(f"{name}: {getattr(self, name).shape[0]} rows for {n} indices")
        if np.isfinite(self.shift_px).all() and not np.isnan(self.confidence + self.peak).any():
            return self  # nothing non-finite anywhere (the usual case): no masks to build
        ok = self.valid
        if not np.all(np.isfinite(self.shift_px[ok])):
            raise ValueError("shift_px: NaN or inf at a valid patch")
        if np.isnan(self.confidence[ok]).any() or np.isnan(self.peak[ok]).any():
            raise ValueError("confidence/peak: NaN at a valid patch")
        return self


class BlockResult(PatchResult):
    """A foreman's answer to a :class:`BlockJob` (same fields as :class:`PatchResult`)."""


# ----------------------------------------------------------------------------------------------- service
class ServiceMessage(WireModel):
    """A message about one service instance ``{role}/{node}/{index}`` and how long it has been up."""

    role: str
    node: str
    index: int = Field(ge=0)
    uptime_s: float = Field(ge=0.0)


class Stats(ServiceMessage):
    """Periodic statistics of a service (``capataz/stats/{role}/{node}/{i}``)."""

    stamp_s: float
    counters: dict[str, int] = Field(default_factory=dict)
    timings_ms: dict[str, float] = Field(default_factory=dict)
    queue_depths: dict[str, int] = Field(default_factory=dict)
    shares: dict[str, float] = Field(default_factory=dict)


class Health(ServiceMessage):
    """Answer of a service's health queryable."""

    ok: bool
    detail: str = ""
    counters: dict[str, int] = Field(default_factory=dict)


class ErrorReply(WireModel):
    """Body of an error reply to a query (travels as the header alone)."""

    kind: str
    error: str


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
    )
}

M = TypeVar("M", bound=WireModel)


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
    for key in message.ARRAYS:
        arr = np.ascontiguousarray(getattr(message, key))
        descriptors.append([key, arr.dtype.str, list(arr.shape), arr.nbytes])
        chunks.append(arr.tobytes())
    try:
        header = msgpack.packb(
            {"v": SCHEMA_VERSION, "t": name, "f": fields, "a": descriptors}, use_bin_type=True
        )
    except (TypeError, ValueError, OverflowError) as exc:
        raise WireError(f"cannot encode {name}: {exc}") from exc
    return b"".join(chunks), header


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
        if key not in cls.ARRAYS:
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
    try:
        return cls.model_validate(values)  # type: ignore[return-value]
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(map(str, err['loc'])) or 'message'}: {err['msg']}" for err in exc.errors()[:5]
        )
        raise WireError(f"{name}: {problems}") from None


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
