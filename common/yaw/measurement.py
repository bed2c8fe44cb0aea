"""A frame's measured patch displacements (:class:`PatchMeasurement`), what each member returns for its
share, and :func:`merge_measurements`, which puts the members' parts back together in patch order."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.types import FloatArray
from common.yaw.grid import IntArray
from common.yaw.settings import YawError


@dataclass(frozen=True, eq=False)
class PatchMeasurement:
    """Displacements of frame k against frame k-1 at the patch centres, full-resolution pixels.

    ``shift_px`` (n, 2) [dx, dy]: content at centre c in frame k-1 is at c + shift in frame k.
    ``confidence`` (n,) is the ratio of the correlation peak to the second peak; ``peak`` (n,) the
    height of the (Gaussian-weighted) phase-correlation peak; ``valid`` (n,) rejects textureless
    and ambiguous patches, ``n_valid`` is how many it keeps.
    """

    indices: IntArray
    shift_px: FloatArray
    confidence: FloatArray
    peak: FloatArray
    valid: npt.NDArray[np.bool_]
    n_valid: int = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_valid", int(np.count_nonzero(self.valid)))


def merge_measurements(
    parts: Sequence[PatchMeasurement], expected: npt.ArrayLike | None = None
) -> PatchMeasurement:
    """One measurement from disjoint per-member parts, in ascending patch index (the order ``conclude`` uses).

    With ``expected``, the parts must cover each of those indices exactly once (a dispatcher's round), else
    no patch index may appear twice; either violation raises :class:`YawError`.
    """
    want = None if expected is None else np.sort(np.asarray(expected, dtype=np.intp))
    if len(parts) == 1 and want is not None and np.array_equal(np.asarray(parts[0].indices, np.intp), want):
        only = parts[0]  # one member computed everything, in order (the usual case): no concatenation
        return PatchMeasurement(
            indices=want,
            shift_px=np.asarray(only.shift_px, dtype=np.float64).reshape(-1, 2),
            confidence=np.asarray(only.confidence, dtype=np.float64),
            peak=np.asarray(only.peak, dtype=np.float64),
            valid=np.asarray(only.valid, dtype=np.bool_),
        )
    indices = (
        np.concatenate([np.asarray(p.indices, dtype=np.intp) for p in parts])
        if parts
        else np.zeros(0, np.intp)
    )
    order = np.argsort(indices, kind="stable")
    if want is not None and not np.array_equal(indices[order], want):
        raise YawError(f"parts cover {indices.size} indices, expected each of {want.size} exactly once")
    if want is None and np.unique(indices).size != indices.size:
        raise YawError("measurement parts overlap (a patch index appears twice)")
    return PatchMeasurement(
        indices=indices[order],
        shift_px=np.concatenate(
            [np.asarray(p.shift_px, dtype=np.float64).reshape(-1, 2) for p in parts] or [np.zeros((0, 2))]
        )[order],
        confidence=np.concatenate(
            [np.asarray(p.confidence, dtype=np.float64) for p in parts] or [np.zeros(0)]
        )[order],
        peak=np.concatenate([np.asarray(p.peak, dtype=np.float64) for p in parts] or [np.zeros(0)])[order],
        valid=np.concatenate([np.asarray(p.valid, dtype=np.bool_) for p in parts] or [np.zeros(0, np.bool_)])[
            order
        ],
    )
