"""A service's counters: thread-safe named counts and recent timings, for its stats (:class:`Counters`).

Every stage of a service records into them (the callbacks, the frames thread, a round); a stage that runs per
frame adds its counts at once (:meth:`Counters.update`)."""

from __future__ import annotations

import threading
from collections import deque

import numpy as np


class Counters:
    """Thread-safe named counters and recent timings (for stats)."""

    def __init__(self, window: int = 200) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}
        self._timings: dict[str, deque[float]] = {}
        self._window = window

    def inc(self, name: str, n: int = 1) -> int:
        with self._lock:
            value = self._counts.get(name, 0) + n
            self._counts[name] = value
            return value

    def get(self, name: str) -> int:
        with self._lock:
            return self._counts.get(name, 0)

    def update(self, counts: dict[str, int], timings_ms: dict[str, float] | None = None) -> None:
        """Several counts and timings at once (one lock)."""
        with self._lock:
            for name, n in counts.items():
                self._counts[name] = self._counts.get(name, 0) + n
            for name, value_ms in (timings_ms or {}).items():
                self._timings.setdefault(name, deque(maxlen=self._window)).append(value_ms)

    def time_ms(self, name: str, value_ms: float) -> None:
        with self._lock:
            self._timings.setdefault(name, deque(maxlen=self._window)).append(value_ms)

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def median_timings_ms(self) -> dict[str, float]:
        with self._lock:
            return {k: float(np.median(v)) for k, v in self._timings.items() if v}
