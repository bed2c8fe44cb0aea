"""One frame's assignment (:class:`Plan`) and the apportionment of patches to members by weight
(:func:`largest_remainder`, Hamilton's method)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError

IndexArray = npt.NDArray[np.int32]


@dataclass(frozen=True)
class Plan:
    """Assignment of one frame: member -> sorted patch indices, and the indices it lacks history for."""

    seq: int
    prev_seq: int
    assignment: dict[str, IndexArray]
    moved: dict[str, IndexArray]

    def shares(self) -> dict[str, float]:
        total = sum(len(v) for v in self.assignment.values())
        return {m: len(v) / total for m, v in self.assignment.items()} if total else {}


def largest_remainder(weights: npt.ArrayLike, total: int) -> npt.NDArray[np.int64]:
    """Integer counts proportional to ``weights`` summing to ``total`` (Hamilton's method)."""
    return np.array(apportion(np.asarray(weights, dtype=np.float64).tolist(), total), dtype=np.int64)


def apportion(weights: list[float], total: int) -> list[int]:
    """:func:`largest_remainder` on a plain list: a plan has a handful of members, where Python floats
    are several times cheaper than numpy's per-call overhead (this runs for every frame, twice per path).
    Ties go to the earlier member."""
    if (
        not isinstance(weights, list)
        or not weights
        or any(not (isinstance(w, float) and math.isfinite(w) and w >= 0) for w in weights)
        or sum(weights) <= 0
    ):
        raise InputError(
            f"weights must be a non-empty 1-D array of finite non-negative values, got {weights}"
        )
    if total < 0:
        raise InputError(f"total must be >= 0, got {total}")
    if len(weights) == 1:
        return [total]
    weight_sum = sum(weights)
    exact = [w / weight_sum * total for w in weights]
    counts = [math.floor(e) for e in exact]
    remainder = total - sum(counts)
    order = sorted(range(len(weights)), key=lambda i: (-(exact[i] - counts[i]), i))
    for i in order[:remainder]:
        counts[i] += 1
    return counts
