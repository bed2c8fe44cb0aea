"""A service's guard of its input stamps: one :class:`~common.streams.StampGuardState` per sensor, and a
health verdict from the recent refusals (services that filter time series: estimator, localizer)."""

from __future__ import annotations

import threading
import time
from collections import deque

from common.streams import GateVerdict, StampGuardSettings, StampGuardState, check_stamp


class InputStamps:
    """Checks each sensor's stamps against its recent ones and the wall clock; remembers recent refusals."""

    def __init__(self, settings: StampGuardSettings | None = None, window_s: float = 5.0) -> None:
        self.settings = settings or StampGuardSettings()
        self.window_s = window_s
        self._states: dict[str, StampGuardState] = {}
        self._refused: deque[float] = deque(maxlen=1024)
        self._lock = threading.Lock()

    def check(self, sensor: str, stamp_s: float) -> tuple[bool, str, str]:
        """``(admitted, reason, detail)`` for one sample of ``sensor``; a confirmed clock jump is admitted
        with reason ``clock_jump``."""
        now = time.monotonic()
        with self._lock:
            state = self._states.get(sensor, StampGuardState())
            state, decision = check_stamp(state, self.settings, stamp_s, now, time.time())
            self._states[sensor] = state
            if decision.verdict is GateVerdict.REFUSE:
                self._refused.append(now)
        return decision.admitted, decision.reason, decision.detail

    def note_refusal(self) -> None:
        """A refusal decided elsewhere (the filter's own stale check): it degrades health too."""
        with self._lock:
            self._refused.append(time.monotonic())

    def recent_refusals(self) -> int:
        cutoff = time.monotonic() - self.window_s
        with self._lock:
            return sum(1 for t in self._refused if t >= cutoff)
