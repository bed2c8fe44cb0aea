"""Every message on the wire: sensors, estimates, work and service messages (the rig's:
:mod:`common.wire.rig`).

Their base and bounds: :mod:`common.wire.schema`; the one codec that carries them and their registry:
:mod:`common.wire.codec`.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import typing
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, create_model, model_validator

from common.bounds import field_bounds
from common.errors import InputError
from common.provenance import Provenance
from common.wire.frame_codec import FrameEncoding
from common.wire.schema import (
    MAX_BUDGET_S,
    MAX_CROP_SIDE_PX,
    MAX_FRAME_SIDE_PX,
    MAX_JOB_PATCHES,
    MAX_JOB_PIXELS,
    MAX_SEQ,
    RIG_ID_PATTERN,
    ArraySpec,
    Uav,
    WireModel,
    frame_id_field,
)
from common.yaw.settings import YawSettings


# ----------------------------------------------------------------------------------------------- sensors
class UavMessage(WireModel):
    """A message of one UAV's stream: its id, the sequence number and the stamp of what it carries."""

    uav: Uav
    seq: int = Field(ge=0, le=MAX_SEQ, default=0)
    stamp_s: float


class Frame(UavMessage):
    """One camera image of a UAV stream (8-bit grey, row-major ``(height, width)``). ``encoding`` is how the
    pixels travel (:mod:`common.wire.frame_codec`): compressed, as the 1-D array ``COMPRESSED_NAME`` that the
    codec decodes once at decode, so a received frame always holds its ``pixels``."""

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {"pixels": ArraySpec("|u1", (None, None))}
    #: the wire array of a compressed frame: its codec's bytes
    COMPRESSED_NAME: ClassVar[str] = "compressed"
    COMPRESSED_SPEC: ClassVar[ArraySpec] = ArraySpec("|u1", (None,))
    seq: int = Field(ge=0, le=MAX_SEQ)  # required
    width: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    height: int = Field(gt=0, le=MAX_FRAME_SIDE_PX)
    encoding: FrameEncoding = "mono8"
    #: the JPEG quality the pixels travel at (jpeg only; None: ``DEFAULT_JPEG_QUALITY``)
    quality: int | None = Field(default=None, ge=1, le=100)
    pixels: np.ndarray
    frame_id: str = frame_id_field("camera")
    #: the id of the stream's rig (``common.wire.rig.RigMessage``) it was taken with; None: not stated
    rig_id: str | None = Field(default=None, pattern=RIG_ID_PATTERN)

    @model_validator(mode="after")
    def _shape_matches(self) -> Frame:
        if self.pixels.shape != (self.height, self.width):
            raise ValueError(
                f"pixels: shape {self.pixels.shape} != (height, width) = ({self.height}, {self.width})"
            )
        if self.quality is not None and self.encoding != "jpeg":
            raise ValueError(f"quality: only a jpeg frame has one, not a {self.encoding} frame")
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
    #: frames: re-searching around the last good pose), ``lost``; None for estimators without one. A pose
    #: not ``tracking`` is a search's guess, not a measurement: its covariance spans the search about the last
    #: trusted pose (:func:`~common.localization.search.untrusted_covariance`).
    tracking_state: Literal["tracking", "searching", "lost"] | None = None
    frame_id: str = frame_id_field("world")


# ----------------------------------------------------------------------------------------------- work
#: Yaw settings only the central stage uses (the lens model): never sent to members.
LOCAL_YAW_SETTINGS = frozenset({"camera"})


class _YawJobBase(BaseModel):
    """The yaw settings a job carries (every member measures with the dispatcher's), bounded at the wire.

    Its fields are generated from :class:`~common.yaw.settings.YawSettings` (:func:`_wire_fields`): the same
    fields but the lens model (only the central stage uses it), with the core's types and bounds, so each
    count and size a member allocates windows and spectra by is bounded before any allocation. A decoded
    value is also a valid ``YawSettings`` (checked once, at decode): :attr:`yaw_settings` is that object.
    """

    # strict: no bool or string for a number; enums (by value on the wire) stay lax
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False, strict=True)
    _yaw_settings: YawSettings = PrivateAttr()

    @model_validator(mode="after")
    def _valid_yaw_settings(self) -> _YawJobBase:
        try:
            self._yaw_settings = _yaw_settings(
                tuple((name, getattr(self, name)) for name in type(self).model_fields)
            )
        except InputError as exc:
            raise ValueError(f"invalid yaw settings: {exc}") from None
        return self

    @classmethod
    def of(cls, settings: YawSettings) -> Self:
        """The wire form of ``settings`` (its lens model stays behind: :data:`LOCAL_YAW_SETTINGS`)."""
        values = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
        return cls.model_validate({k: v for k, v in values.items() if k not in LOCAL_YAW_SETTINGS})

    @property
    def yaw_settings(self) -> YawSettings:
        """The core's settings object (no lens model)."""
        return self._yaw_settings


def _wire_fields() -> dict[str, Any]:
    """The wire fields of :class:`YawSettings`: its types, its bounds; required (a job states them all)."""
    hints = typing.get_type_hints(YawSettings)
    bounds = field_bounds(YawSettings)
    fields: dict[str, Any] = {}
    for name in (f.name for f in dataclasses.fields(YawSettings) if f.name not in LOCAL_YAW_SETTINGS):
        limits = bounds.get(name)
        keywords: dict[str, Any] = {}
        if limits is not None:
            keywords = {
                k: getattr(limits, k) for k in ("gt", "ge", "lt", "le") if getattr(limits, k) is not None
            }
        if isinstance(hints[name], type) and issubclass(hints[name], enum.Enum):
            keywords["strict"] = False
        fields[name] = (hints[name], Field(**keywords))
    return fields


if TYPE_CHECKING:

    class YawJobSettings(_YawJobBase):
        def __getattr__(self, name: str) -> Any: ...

else:
    YawJobSettings = create_model(
        "YawJobSettings",
        __base__=_YawJobBase,
        __module__=__name__,
        __doc__=_YawJobBase.__doc__,
        **_wire_fields(),
    )


@functools.lru_cache(maxsize=16)
def _yaw_settings(values: tuple[tuple[str, object], ...]) -> YawSettings:
    """A job's core settings: jobs carry the same few, so each is built and checked once, then looked up."""
    return YawSettings(**dict(values))  # type: ignore[arg-type]


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
    budget_s: float = Field(gt=0.0, le=MAX_BUDGET_S, default=1.0)

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

    @property
    def member(self) -> str:
        """The instance's name, ``role/node/index`` (the key of the member in every report)."""
        return f"{self.role}/{self.node}/{self.index}"


class Stats(ServiceMessage):
    """Periodic statistics of a service (``capataz/stats/{role}/{node}/{i}``)."""

    stamp_s: float
    counters: dict[str, int] = Field(default_factory=dict)
    timings_ms: dict[str, float] = Field(default_factory=dict)
    queue_depths: dict[str, int] = Field(default_factory=dict)
    shares: dict[str, float] = Field(default_factory=dict)
    #: CPU seconds (user + system, every thread) the member's process used since it started
    #: (``time.process_time``): a role's CPU per frame is its growth over the frames of a window
    cpu_s: float = Field(ge=0.0, default=0.0)
    #: the machine the member runs on (its host name: a container's in compose), "" when unknown
    host: str = Field(default="", max_length=255)
    #: the UAV streams the member serves (a master's, an estimator's; a camera's several), empty for
    #: members of every stream (workers, foremen, the router)
    uavs: list[Uav] = Field(default_factory=list, max_length=64)


class Health(ServiceMessage):
    """Answer of a service's health queryable."""

    ok: bool
    detail: str = ""
    counters: dict[str, int] = Field(default_factory=dict)


class ErrorReply(WireModel):
    """Body of an error reply to a query (travels as the header alone)."""

    kind: str
    error: str
