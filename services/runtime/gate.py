"""The one input gate of a service: every input of a UAV stream (frames, IMU, range, yaw, poses) passes it
once, where it arrives, before anything else sees it.

It is :func:`common.streams.admit_frame` with one state per sensor, the sender as the transport declares it
(:func:`~services.runtime.transport.source_of`) and the receiver's clocks: a sample of another UAV, of a
second sender within the epoch, with a non-finite stamp, a stamp in the future (of the wall clock, for
wall-clock streams, or beyond the stream's rate bound), a stamp or a ``seq`` that jumps, goes back or a
size that changes, is **refused**: counted as ``refused_{sensor}_{reason}``, logged (the first 20, then every
100th), remembered for health, and it changes no consumer state. A real restart (a camera restarted from seq
0, a clock that jumped) is adopted once ``confirm_frames`` consistent samples in a row say so, or once the
epoch's sender has been silent for ``silence_s``: that is the bounded, documented resynchronisation; it is
counted as ``epochs_{sensor}`` and the verdict is ``NEW_EPOCH`` so the consumer can start over.

Frames are numbered by their own ``seq``; the other sensors by their arrival order at this gate (publishers
outside capataz need not number their samples), so for them the gate checks stamps, sender and UAV.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Protocol

from common.streams import Decision, FrameGateSettings, FrameGateState, FrameKey, GateVerdict, admit_frame
from common.wire.messages import Frame, UavMessage
from services.runtime.counters import Counters

#: recent refusals kept for health (a burst beyond this still reads degraded)
REFUSALS_KEPT = 1024


class _Reporter(Protocol):
    counters: Counters

    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None: ...


class InputGate:
    """One gate state per sensor of one UAV stream; thread-safe (zenoh's callbacks may run on many threads).

    ``window_s``: how long a refusal keeps the service's health degraded (:meth:`recent_refusals`)."""

    def __init__(
        self,
        uav: str,
        service: _Reporter,
        settings: FrameGateSettings | None = None,
        window_s: float = 5.0,
    ) -> None:
        self.uav = uav
        self.settings = settings or FrameGateSettings()
        self.window_s = window_s
        self._service = service
        self._states: dict[str, FrameGateState] = {}
        self._arrivals: dict[str, int] = {}
        self._refused: deque[float] = deque(maxlen=REFUSALS_KEPT)
        self._lock = threading.Lock()

    def admit(
        self,
        sensor: str,
        msg: UavMessage,
        source: str | None,
        now_s: float | None = None,
        wall_s: float | None = None,
    ) -> Decision:
        """The gate's decision about one decoded input of ``sensor`` (``camera``, ``imu``, ``range``,
        ``yaw``, ``vo``, ...) from ``source`` (None: it declared none); ``now_s``/``wall_s``: when it arrived
        (monotonic / wall clock; default: now). Refusals and restarts are counted and logged here."""
        now = time.monotonic() if now_s is None else now_s
        wall = time.time() if wall_s is None else wall_s
        if isinstance(msg, Frame):
            key, seq = FrameKey(msg.width, msg.height, msg.encoding), msg.seq
        else:
            key = FrameKey(0, 0, sensor)
        with self._lock:
            if not isinstance(msg, Frame):
                seq = self._arrivals[sensor] = self._arrivals.get(sensor, -1) + 1
            state = self._states.get(sensor, FrameGateState())
            state, decision = admit_frame(
                state, self.settings, self.uav, msg.uav, seq, msg.stamp_s, key, now, wall, source
            )
            self._states[sensor] = state
            if decision.verdict is GateVerdict.REFUSE:
                self._refused.append(now)
        if decision.verdict is GateVerdict.REFUSE:
            self._service.count_error(
                f"refused_{sensor}_{decision.reason}", f"{sensor} input refused", decision.detail
            )
        elif decision.verdict is GateVerdict.NEW_EPOCH and state.epoch > 0:
            self._service.count_error(
                f"epochs_{sensor}", f"{sensor} stream restarted", decision.detail or decision.reason
            )
        return decision

    def epoch(self, sensor: str) -> int:
        """The sensor's current epoch (-1 before its first admitted input)."""
        with self._lock:
            return self._states.get(sensor, FrameGateState()).epoch

    def note_refusal(self) -> None:
        """A refusal decided after the gate (a filter's own stale check): it degrades health too."""
        with self._lock:
            self._refused.append(time.monotonic())

    def recent_refusals(self) -> int:
        """Refusals in the last ``window_s``."""
        cutoff = time.monotonic() - self.window_s
        with self._lock:
            return sum(1 for t in self._refused if t >= cutoff)
