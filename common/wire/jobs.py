"""The cluster's work messages: a share of a frame's patches (:class:`PatchJob`, a master's block for a
foreman :class:`BlockJob`), its measured shifts (:class:`PatchResult`, :class:`BlockResult`) and the yaw
settings every member measures with (:class:`YawJobSettings`). Re-exported by :mod:`common.wire.messages`,
the list of every message; their base and bounds: :mod:`common.wire.schema`.
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
from common.wire import frame_codec
from common.wire.schema import (
    MAX_BUDGET_S,
    MAX_CROP_SIDE_PX,
    MAX_FRAME_SIDE_PX,
    MAX_JOB_PATCHES,
    MAX_JOB_PIXELS,
    MAX_SEQ,
    ArraySpec,
    Uav,
    WireError,
    WireModel,
)
from common.yaw.grid import crops_at
from common.yaw.settings import YawSettings

#: how a job's pixels travel when they go as one image (``band``): raw, zstd-compressed (lossless) or JPEG
#: (lossy, :data:`~common.wire.frame_codec.DEFAULT_JPEG_QUALITY`)
JobEncoding = Literal["mono8", "zstd", "jpeg"]

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
        """The wire form of ``settings`` (its lens model stays behind: :data:`LOCAL_YAW_SETTINGS`), resolved
        for the stream's frames (:func:`~common.yaw.grid.for_frame`): a job states its pyramid level."""
        if settings.pyramid_level is None:
            raise InputError(
                "a job's yaw settings state their pyramid level: resolve them for the frames first"
            )
        values = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
        return cls.model_validate({k: v for k, v in values.items() if k not in LOCAL_YAW_SETTINGS})

    @property
    def yaw_settings(self) -> YawSettings:
        """The core's settings object (no lens model)."""
        return self._yaw_settings


def _wire_fields() -> dict[str, Any]:
    """The wire fields of :class:`YawSettings`: its types, its bounds; required (a job states them all).
    A value the core may leave to be resolved (an optional bound: the pyramid level that follows the frame's
    size) is stated resolved: the master resolves its settings for the stream's frames
    (:func:`~common.yaw.grid.for_frame`), so a job's type is the value's without None."""
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
            if limits.optional:
                hints[name] = next(t for t in typing.get_args(hints[name]) if t is not type(None))
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

    The new frame's patches may travel as one ``band`` of its level image instead (``crops`` then empty):
    fewer bytes where patches overlap. The band's bytes are in ``band_encoding`` (``mono8``; ``zstd``,
    :mod:`common.wire.frame_codec`'s lossless codec; or ``jpeg``, lossy), its shape is ``band_shape`` and
    ``corners`` gives each index's crop corner ``[row, col]`` in it. Decoding cuts the crops from the band
    (bit-identical to the sender's but for ``jpeg``) and drops it: a decoded job always holds ``crops``.

    A ``transient`` job is a turning pair's second pass (:data:`~common.yaw.stages.RefineMeasure`): its
    crops are frame ``seq`` turned back, measured against the previous crops of the same indices (sent with
    it, or, to a foreman, none: it holds them) and nothing of it is kept.
    """

    ARRAYS: ClassVar[dict[str, ArraySpec]] = {
        "indices": ArraySpec("<i4", (None,)),
        "crops": ArraySpec("|u1", (None, None, None)),
        "prev_indices": ArraySpec("<i4", (None,)),
        "prev_crops": ArraySpec("|u1", (None, None, None)),
        "band": ArraySpec("|u1", (None,)),
        "corners": ArraySpec("<i4", (None, 2)),
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
    band: np.ndarray = Field(default_factory=lambda: np.zeros(0, np.uint8))
    band_shape: tuple[int, int] = (0, 0)
    band_encoding: JobEncoding = "mono8"
    corners: np.ndarray = Field(default_factory=lambda: np.zeros((0, 2), np.int32))
    transient: bool = False

    @model_validator(mode="after")
    def _consistent(self) -> PatchJob:
        if self.indices.shape[0] > MAX_JOB_PATCHES:
            raise ValueError(f"indices: {self.indices.shape[0]} patches > {MAX_JOB_PATCHES}")
        if self.band.size or self.corners.size or self.band_shape != (0, 0):
            crops = _crops_of_band(self)
            # the model is frozen; this is its own validation, before anyone holds it
            object.__setattr__(self, "crops", crops)
            object.__setattr__(self, "band", self.band[:0])
            object.__setattr__(self, "corners", self.corners[:0])
            object.__setattr__(self, "band_shape", (0, 0))
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
        if self.transient and self.prev_indices.size and not np.array_equal(self.prev_indices, self.indices):
            raise ValueError("prev_indices: a transient job's must be its indices, or none")
        return self


def band_decode_pixels(band_bytes: int, band_shape: tuple[int, int], crop_pixels: int) -> int:
    """What decoding a band job holds at once, in bytes: the band's bytes and their copy, the band and its
    undone row deltas, the crops cut from it and the previous crops (``crop_pixels``). A job is refused
    above :data:`MAX_JOB_PIXELS`, as a job of crops alone is; a sender sends crops instead of such a band."""
    return 2 * band_bytes + 2 * band_shape[0] * band_shape[1] + crop_pixels


def _crops_of_band(job: PatchJob) -> np.ndarray:
    """The crops of a job that carries a band (see :class:`PatchJob`), every size checked before anything
    is decompressed or cut (a ValueError names what is wrong)."""
    side = int(job.settings.patch_size_px)
    height, width = job.band_shape
    n = job.indices.shape[0]
    if job.crops.shape[0]:
        raise ValueError("band: a job carries its crops or a band, not both")
    if not (0 < height <= MAX_FRAME_SIDE_PX and 0 < width <= MAX_FRAME_SIDE_PX):
        raise ValueError(f"band_shape: {job.band_shape} must be 1..{MAX_FRAME_SIDE_PX} px a side")
    if height < side or width < side:
        raise ValueError(f"band_shape: {job.band_shape} is smaller than a {side} px patch")
    pixels = band_decode_pixels(job.band.size, (height, width), n * side * side + job.prev_crops.size)
    if pixels > MAX_JOB_PIXELS:
        raise ValueError(f"band: {pixels} bytes to decode with its crops > {MAX_JOB_PIXELS}")
    if job.corners.shape[0] != n:
        raise ValueError(f"corners: {job.corners.shape[0]} corners for {n} indices")
    corners = job.corners
    if n and (corners.min() < 0 or corners[:, 0].max() > height - side or corners[:, 1].max() > width - side):
        raise ValueError(f"corners: a {side} px crop does not fit in the {height}x{width} band")
    try:
        image = frame_codec.decode(job.band.data, job.band_encoding, width, height)
    except WireError as exc:
        raise ValueError(f"band: {exc}") from None
    return crops_at(image, corners[:, 0], corners[:, 1], side)


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
