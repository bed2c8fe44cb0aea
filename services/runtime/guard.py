"""A dispatcher's defence in depth, wired to a service: trust vetting, one frame source, churn limit.

Thin glue between the pure cores (:mod:`common.dispatch.trust`, :mod:`common.dispatch.vetting`,
:mod:`common.dispatch.admission`) and a service's counters and log: the master calls
:meth:`admit` on its frames thread (each turn: the received frames' sources and the churn quarantine),
:meth:`note_alive` in its liveliness callback (hands off only) and :meth:`vet` after each frame's round.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from common.dispatch import TrustMonitor, TrustSettings
from common.dispatch.admission import ChurnLimiter, SourceLock
from common.dispatch.vetting import round_outcomes
from common.yaw import YawSettings
from common.yaw.measurement import PatchMeasurement
from services.runtime.counters import Counters

logger = logging.getLogger(__name__)


class DispatchGuard:
    """Per service: the frame source lock, the churn limiter and the trust monitor."""

    def __init__(self, name: str, counters: Counters, enabled: bool = True) -> None:
        self.name = name
        self.counters = counters
        self.enabled = enabled
        self.sources = SourceLock()
        self.churn = ChurnLimiter()
        self._lock = threading.Lock()
        #: one for every dispatcher of the service: credit and suspensions outlive a stream's restart
        self._monitor = TrustMonitor(TrustSettings(enabled=enabled))

    def monitor(self) -> TrustMonitor:
        """The service's trust monitor, for a new dispatcher (disabled when the guard is)."""
        return self._monitor

    def admit(self, received: Sequence[tuple[str | None, float]]) -> list[bool]:
        """One turn of the frames thread, in one call: whether each received frame, sent by ``source``
        (:func:`~services.runtime.transport.source_of` its sample) and received at ``now_s`` (monotonic), is
        the followed source's (others are dropped, counted, logged); and the members whose liveliness
        churns are paused in the service's trust monitor (which every dispatcher of the service holds)
        until their quarantine ends. Nothing of this module is called once it has called out."""
        if not self.enabled:
            return [True] * len(received)
        admitted: list[bool] = []
        for source, now_s in received:
            followed = self.sources.admit(source, now_s)
            admitted.append(followed)
            if not followed:
                n = self.counters.inc("frames_foreign")
                if n <= 5 or n % 100 == 0:
                    logger.warning(
                        "%s: dropping frames of another source %s (#%d)", self.name, source or "anonymous", n
                    )
        with self._lock:
            ends = self.churn.quarantine_ends(time.monotonic())
        for member, until_s in ends.items():
            self._monitor.suspend(member, until_s)
        return admitted

    def note_alive(self, member: str, joined: bool) -> None:
        with self._lock:
            self.churn.allow(member, joined, time.monotonic())

    def vet(
        self,
        trust: TrustMonitor | None,
        owners: Sequence[str],
        parts: Sequence[PatchMeasurement],
        merged: Any,
        centres_px: np.ndarray,
        settings: YawSettings,
    ) -> None:
        """Judge a frame's members against its robust fit; suspend, count and report inconsistent ones."""
        if trust is None or not trust.settings.enabled:
            return
        now = time.monotonic()
        for verdict in trust.observe(round_outcomes(owners, parts, merged, centres_px, settings), now):
            self.counters.inc("trust_suspensions")
            logger.warning(
                "%s: suspending %s for %.0f s: %s",
                self.name,
                verdict.member,
                verdict.until_s - now,
                verdict.reason,
            )
