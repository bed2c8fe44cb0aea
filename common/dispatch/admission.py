"""Who is let in: one frame source per stream, and liveliness churn limited per key (pure decisions).

Without access control anybody can publish frames on a camera key or declare liveliness tokens. Zenoh 1.10
does not tell a Python subscriber which participant sent a sample: a publisher may *declare* a source
(``source_info``: its entity id and a sequence number), which the capataz camera does. So:

- :class:`SourceLock` follows one declared source per stream: the first one seen, for as long as it keeps
  sending (``hold_s``); frames of other sources, and frames that declare none while a declared source is
  live, are dropped and counted per source. A flood of anonymous forged frames cannot starve the camera.
  It is no authentication: a forger that copies the camera's declared id, or that declares one first, is
  followed. Only the secure profile (mutual TLS + access control) authenticates senders.
- :class:`ChurnLimiter` ignores a key whose liveliness changes more than ``max_changes`` times within
  ``window_s``, for ``quarantine_s``: a token declared and undeclared in a loop cannot make the dispatcher
  re-plan every frame. A leave is always honoured.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from common.bounds import Bounded, bounded

#: the source of samples that declare none
ANONYMOUS = "anonymous"


@dataclass(frozen=True)
class AdmissionSettings(Bounded):
    hold_s: float = bounded(1.0, gt=0.0)
    max_changes: int = bounded(6, ge=1)
    window_s: float = bounded(10.0, gt=0.0)
    quarantine_s: float = bounded(30.0, gt=0.0)
    #: how many distinct sources / keys are remembered (bounded memory under a flood of new ids)
    max_tracked: int = bounded(1024, ge=1)


class SourceLock:
    """Follows one declared frame source at a time (see the module docstring)."""

    def __init__(self, settings: AdmissionSettings | None = None) -> None:
        self.settings = settings or AdmissionSettings()
        self.source: str | None = None
        self._last_s = -math.inf
        self.dropped: dict[str, int] = {}

    def admit(self, source: str | None, now_s: float) -> bool:
        """Whether a frame from ``source`` (None: declared none) is processed; a refusal is counted."""
        name = source or ANONYMOUS
        live = self.source is not None and now_s - self._last_s <= self.settings.hold_s
        if name == self.source or (not live and source is not None):
            self.source, self._last_s = name, now_s
            return True
        if not live and source is None:
            return True  # nobody declared a source lately (an older camera, a replay tool): accept
        if name in self.dropped or len(self.dropped) < self.settings.max_tracked:
            self.dropped[name] = self.dropped.get(name, 0) + 1
        return False


class ChurnLimiter:
    """Per-key liveliness change rate limit (see the module docstring)."""

    def __init__(self, settings: AdmissionSettings | None = None) -> None:
        self.settings = settings or AdmissionSettings()
        self._changes: dict[str, deque[float]] = {}
        self._quarantined: dict[str, float] = {}
        self.refused = 0

    def allow(self, key: str, joined: bool, now_s: float) -> bool:
        """Whether a join (or leave) of ``key`` is applied; leaves always are, joins of a churning key not."""
        s = self.settings
        if len(self._changes) >= s.max_tracked and key not in self._changes:
            self._forget_old(now_s)
        changes = self._changes.setdefault(key, deque())
        changes.append(now_s)
        while changes and now_s - changes[0] > s.window_s:
            changes.popleft()
        if len(changes) > s.max_changes:
            self._quarantined[key] = now_s + s.quarantine_s
        if joined and self._quarantined.get(key, -math.inf) > now_s:
            self.refused += 1
            return False
        return True

    def quarantined(self, now_s: float) -> frozenset[str]:
        return frozenset(self.quarantine_ends(now_s))

    def quarantine_ends(self, now_s: float) -> dict[str, float]:
        """Keys quarantined now and when their quarantine ends."""
        return {k: until for k, until in self._quarantined.items() if until > now_s}

    def _forget_old(self, now_s: float) -> None:
        s = self.settings
        for key in [k for k, c in self._changes.items() if not c or now_s - c[-1] > s.window_s]:
            del self._changes[key]
        for key in [k for k, until in self._quarantined.items() if until <= now_s]:
            del self._quarantined[key]
        while len(self._changes) >= s.max_tracked:  # all recent: drop the oldest to stay bounded
            del self._changes[next(iter(self._changes))]
