"""A small time-ordered buffer with a bounded lag, for multi-rate asynchronous sensor input.

Samples from different sensors arrive slightly out of order. The buffer holds each sample until it is
``max_lag_s`` older than the newest stamp seen, then releases everything due in stamp order. A sample that
arrives after samples with a later stamp were already released (stale), or that repeats a pending stamp of
the same sensor (duplicate), is refused: :meth:`TimeOrderedBuffer.push` returns a :class:`Refusal`.
"""

from __future__ import annotations

import enum
import heapq
import itertools
import math
from dataclasses import dataclass
from typing import Generic, TypeVar

from common.errors import InputError

T = TypeVar("T")


class Refusal(enum.Enum):
    """Why a sample was not queued."""

    STALE = "stale"
    DUPLICATE = "duplicate"
    OVERFLOW = "overflow"


@dataclass(frozen=True)
class Timed(Generic[T]):
    """A released sample with its stamp and sensor name."""

    stamp_s: float
    sensor: str
    item: T


class TimeOrderedBuffer(Generic[T]):
    """Reorders samples by stamp within ``max_lag_s``; bounded to ``max_items`` pending samples."""

    def __init__(self, max_lag_s: float = 0.05, max_items: int = 4096) -> None:
        if not (math.isfinite(max_lag_s) and max_lag_s >= 0.0):
            raise InputError(f"max_lag_s must be finite and >= 0, got {max_lag_s}")
        if max_items < 1:
            raise InputError(f"max_items must be >= 1, got {max_items}")
        self.max_lag_s = float(max_lag_s)
        self.max_items = int(max_items)
        self._heap: list[tuple[float, int, int, str, T]] = []
        self._pending: set[tuple[str, float]] = set()
        self._order = itertools.count()
        self._released_until_s = -math.inf
        self._newest_s = -math.inf
        self._last_released: dict[str, float] = {}

    def __len__(self) -> int:
        return len(self._heap)

    @property
    def released_until_s(self) -> float:
        """Stamp of the last released sample (``-inf`` before the first)."""
        return self._released_until_s

    def push(self, stamp_s: float, sensor: str, item: T, rank: int = 0) -> Refusal | None:
        """Queue a sample; returns ``None`` when accepted, else why it was refused.

        Samples with equal stamps are released by ``rank`` (lower first), then in arrival order.
        """
        if not math.isfinite(stamp_s):
            raise InputError(f"stamp_s must be finite, got {stamp_s}")
        if stamp_s < self._released_until_s:
            return Refusal.STALE
        key = (sensor, stamp_s)
        if key in self._pending or self._last_released.get(sensor) == stamp_s:
            return Refusal.DUPLICATE
        if len(self._heap) >= self.max_items:
            return Refusal.OVERFLOW
        heapq.heappush(self._heap, (stamp_s, int(rank), next(self._order), sensor, item))
        self._pending.add(key)
        self._newest_s = max(self._newest_s, stamp_s)
        return None

    def first_pending(self, sensor: str) -> T | None:
        """The earliest pending sample of ``sensor`` (None: none pending), left in the buffer."""
        found = min((entry for entry in self._heap if entry[3] == sensor), default=None)
        return None if found is None else found[4]

    def pop_due(self) -> list[Timed[T]]:
        """Release, in stamp order, every sample at least ``max_lag_s`` older than the newest stamp."""
        return self._release(self._newest_s - self.max_lag_s)

    def drain(self) -> list[Timed[T]]:
        """Release everything pending, in stamp order (end of stream)."""
        return self._release(math.inf)

    def _release(self, until_s: float) -> list[Timed[T]]:
        out: list[Timed[T]] = []
        while self._heap and self._heap[0][0] <= until_s:
            stamp_s, _, _, sensor, item = heapq.heappop(self._heap)
            self._pending.discard((sensor, stamp_s))
            self._released_until_s = stamp_s
            self._last_released[sensor] = stamp_s
            out.append(Timed(stamp_s=stamp_s, sensor=sensor, item=item))
        return out
