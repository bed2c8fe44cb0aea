"""The master's frames on their way in: zenoh's callback hands each sample off, the frames thread gates it.

:meth:`FrameIntake.receive` is all zenoh's callback does: the sample and its arrival times into a bounded
inbox (as zenoh-python's examples hand samples to a channel). :meth:`FrameIntake.gate_received`, on the
master's frames thread, takes every sample received so far through the source lock, the decoder and the
service's input gate (:class:`services.runtime.gate.InputGate`), in arrival order and with the arrival
times, so the gate decides as it did in the callback. Admitted frames are kept as the recent ones (a standby
taking over measures them) and, when leading, queued for the yaw stage in a short FIFO whose oldest frame is
dropped (counted) beyond ``frame_queue``.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import zenoh

from common.rig import Rig
from common.streams import GateVerdict
from common.wire.messages import Frame
from services.master.settings import MasterSettings
from services.runtime.gate import InputGate
from services.runtime.guard import DispatchGuard
from services.runtime.handoff import FrameQueue
from services.runtime.rig_follow import RigFollower
from services.runtime.service import ConfiguredService
from services.runtime.transport import source_of

#: how long the frames thread waits for the answer when a frame names a rig not received yet (s): at the
#: start of a stream the camera's rig and first frame race; 1 s lost a first frame under two busy loops and a
#: second test process
RIG_WAIT_S = 3.0
#: frame samples received but not gated yet, at most (beyond, the oldest is dropped and counted): the frames
#: thread gates them all before each frame it measures, so this only fills while it is stalled
INBOX_CAPACITY = 256


class FrameFifo(deque[tuple[int, Frame]]):
    """The gated frames waiting for the yaw stage, oldest first, at most ``capacity`` (beyond, the oldest is
    dropped; :attr:`dropped` counts each drop once). Only the frames thread puts and takes (the intake's
    turn appends to it directly, as a deque), so it needs no lock; :meth:`depth` is safe from any thread."""

    def __init__(self, capacity: int) -> None:
        super().__init__(maxlen=capacity)
        self.dropped = 0

    def depth(self) -> int:
        return len(self)

    def take(self, timeout_s: float = 0.0) -> tuple[int, Frame] | None:
        """The oldest frame, None when empty (``timeout_s`` is not waited: the frames thread fills it)."""
        return self.popleft() if self else None


@dataclass(frozen=True)
class Received:
    """A frame sample as zenoh's callback hands it off: with the receiver's monotonic and wall-clock times."""

    sample: zenoh.Sample
    now_s: float
    wall_s: float


class FrameIntake:
    """One master's inbox, stream gate, recent frames and queue (see the module docstring)."""

    def __init__(
        self, service: ConfiguredService[MasterSettings], guard: DispatchGuard, settings: MasterSettings
    ) -> None:
        self.service = service
        self.guard = guard
        self.uav = settings.uav
        #: the master's one input gate (frames here, IMU samples in the gyro prior); its refusals make health
        self.gate = InputGate(settings.uav, service, settings.gate_settings())
        #: what zenoh's callback hands off
        self.inbox: FrameQueue[Received] = FrameQueue(INBOX_CAPACITY)
        #: frames wait in a short FIFO: a stalled round (a member that froze, until its deadline) delays the
        #: next frames instead of dropping them; beyond ``frame_queue`` frames the oldest is dropped (counted)
        self.slot = FrameFifo(settings.frame_queue)
        self.recent: deque[tuple[int, Frame]] = deque(maxlen=settings.recent_frames)
        #: the stream's rigs (None: the master measures with its own options); the rig of each admitted
        #: frame by seq, as many as the recent frames (a take-over measures them again)
        self.rigs: RigFollower | None = None
        self.frame_rigs: dict[int, Rig | None] = {}
        self.recent_lock = threading.Lock()

    def receive(self, sample: zenoh.Sample) -> None:
        """Zenoh's thread: hand the sample off with its arrival times."""
        if self.inbox.put(Received(sample, time.monotonic(), time.time())):
            self.service.counters.inc("frames_dropped")

    def gate_received(self, leading: bool) -> None:
        """Frames thread: every sample received so far through the gate, in arrival order; the admitted ones
        kept as recent frames and, when ``leading``, queued. The counts are added once."""
        counts: dict[str, int] = {}
        self._turn(leading, None, counts)
        if counts:
            self.service.counters.update(counts)

    def next_frame(self, leading: bool, wait_s: float, counts: dict[str, int]) -> tuple[int, Frame] | None:
        """One turn of the frames thread: waits up to ``wait_s`` for a sample when none is received or
        queued, gates them as :meth:`gate_received` (its counts added to ``counts``, for the caller to add
        to the counters with the frame's), then the oldest queued (epoch, frame) when ``leading``."""
        return self._turn(leading, wait_s, counts)

    def _turn(self, leading: bool, wait_s: float | None, counts: dict[str, int]) -> tuple[int, Frame] | None:
        """:meth:`next_frame` (``wait_s`` None: only the gate). Written so that nothing of this module is
        called once it has called out: each sample's admission inline, the guard asked once for all their
        sources, the admitted frames queued together (the FIFO as a deque)."""
        slot = self.slot
        if wait_s is not None and not slot and self.inbox.depth() == 0:
            self.inbox.wait(wait_s)
        received = self.inbox.drain()
        service = self.service
        sources: list[tuple[str | None, float]] = []
        for r in received:  # a loop, not a comprehension: that would be a call into this module
            sources.append((source_of(r.sample), r.now_s))
        admitted: list[tuple[int, Frame]] = []
        followed = self.guard.admit(sources)
        for r, (source, _), from_followed in zip(received, sources, followed, strict=True):
            frame = service.decode_sample(r.sample, Frame) if from_followed else None
            if frame is None:
                continue
            counts["frames_in"] = counts.get("frames_in", 0) + 1
            decision = self.gate.admit("camera", frame, source, r.now_s, r.wall_s)
            if decision.verdict is GateVerdict.REFUSE:
                continue
            if decision.verdict is GateVerdict.NEW_EPOCH:
                counts["epochs"] = counts.get("epochs", 0) + 1
            counts["frames_missing"] = counts.get("frames_missing", 0) + decision.gap
            if self.rigs is not None:  # a frame naming a rig not received is refused (counted, asked for)
                rig, known = self.rigs.rig_of(frame, RIG_WAIT_S)
                if not known:
                    continue
                self.frame_rigs[frame.seq] = rig
                if len(self.frame_rigs) > 2 * (self.recent.maxlen or 1):
                    del self.frame_rigs[next(iter(self.frame_rigs))]
            admitted.append((self.gate.epoch("camera"), frame))
        with self.recent_lock:
            self.recent.extend(admitted)
        if leading:
            for item in admitted:
                if len(slot) == slot.maxlen:  # the oldest is dropped to make room
                    slot.dropped += 1
                    counts["frames_dropped"] = counts.get("frames_dropped", 0) + 1
                slot.append(item)
        return slot.popleft() if leading and wait_s is not None and slot else None
