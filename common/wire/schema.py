"""The wire's building blocks: :class:`WireModel` (the base of every message), array specs and bounds.

Every message (:mod:`common.wire.messages`) is a frozen pydantic model whose array fields
(:attr:`WireModel.ARRAYS`) travel as raw bytes beside a msgpack header (:mod:`common.wire.codec`). Every
count and size a sender chooses is bounded here, so a hostile sender gets a :class:`WireError`, never an
allocation of its choosing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, model_validator

from common.errors import CapatazError
from common.rig import RIG_ID_HEX

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
MAX_BUDGET_S = 10.0  # a job's time budget: a worker may hold a job (and its crops) this long at most


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
#: Frames of reference (``frame_id``; docs/data.md "Keys and frames", ROS REP 103): ``world`` (ENU, z up),
#: ``body`` (FLU: x forward, y left, z up), ``camera`` (OpenCV optical: x right, y down, z along the axis).
FRAME_ID_PATTERN = r"^[A-Za-z0-9_./-]{1,64}$"
#: a rig id (:attr:`common.rig.Rig.rig_id`): :data:`common.rig.RIG_ID_HEX` lower-case hex digits.
RIG_ID_PATTERN = rf"^[0-9a-f]{{{RIG_ID_HEX}}}$"


def frame_id_field(default: str) -> Any:
    """The ``frame_id`` of a message: the frame its data is expressed in (estimates: their parent frame)."""
    return Field(default=default, pattern=FRAME_ID_PATTERN)
