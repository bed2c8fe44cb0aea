"""The estimator's backlog: the frame queue, where frames are skipped evenly when the filter is behind
(never in a burst), and the samples held back until the frames before them are pushed.

:class:`Backlog` is what the service's callbacks hand samples and frames to, and what its estimator thread
takes them from, one turn at a time (:meth:`Backlog.next`): the samples to apply, then at most one frame.

The visual odometry pairs each frame it uses with the one it used before. On paper C's flight (20 fps) pairs
up to 5 frames apart are as good as consecutive ones (end-point error 0.67, 0.56, 0.80 and 0.46 cm for
every 2nd to 5th frame against 0.77 cm with every frame), every 6th ends 1.6 cm off (4.3 cm on the way),
every 8th 26 cm; a burst of lost frames (a second in three) breaks the chain: the pair across the gap fails
and the motion during the gap is lost (2.1 m off). So a full queue does not refuse the newest frame: it
skips the queued frame whose removal leaves the shortest gap between the frames the VO will pair (counting
the frame the VO used last), and the pairs' spacing grows evenly with the backlog, up to ``max_pair_s``.
Beyond that the queue grows instead (latency rather than pairs the VO cannot handle) until it spans
``max_backlog_s`` behind the frame the VO used last; only then are pairs spaced wider.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

from common.errors import InputError
from services.runtime.handoff import WorkQueue


class Stamped(Protocol):
    @property
    def stamp_s(self) -> float: ...


F = TypeVar("F", bound=Stamped)
S = TypeVar("S", bound=Stamped)


class SpacedFrameQueue(Generic[F]):
    """FIFO of frames (stamp order) that, beyond ``capacity``, admits the newest frame and skips the queued
    one whose neighbours are closest in time, as long as they are at most ``max_pair_s`` apart or the queue
    spans more than ``max_backlog_s``. Thread-safe: callbacks offer, the estimator thread takes."""

    #: frames queued at most, whatever the stamps say
    HARD_CAPACITY = 128

    def __init__(self, capacity: int, max_pair_s: float = math.inf, max_backlog_s: float = 0.0) -> None:
        if not 2 <= capacity <= self.HARD_CAPACITY:
            raise InputError(f"the frame queue needs a capacity of 2 to {self.HARD_CAPACITY}, got {capacity}")
        if not (max_pair_s > 0.0 and max_backlog_s >= 0.0):
            raise InputError("the frame queue needs max_pair_s > 0 and max_backlog_s >= 0")
        self.capacity = capacity
        self.max_pair_s = max_pair_s
        self.max_backlog_s = max_backlog_s
        #: queued frames with the number of frames skipped just before each
        self._frames: deque[tuple[F, int]] = deque()
        self._lock = threading.Lock()
        #: stamp of the frame the estimator took last (the VO's previous frame)
        self._taken_s = -math.inf

    def offer(self, frame: F) -> F | None:
        """Queue ``frame`` (newer than every queued one); returns the frame skipped to make room, if any."""
        with self._lock:
            self._frames.append((frame, 0))
            if len(self._frames) <= self.capacity:
                return None
            i, gap_s = self._skip_candidate()
            behind_s = frame.stamp_s - (
                self._taken_s if self._taken_s > -math.inf else self._frames[0][0].stamp_s
            )
            if (
                gap_s > self.max_pair_s
                and behind_s <= self.max_backlog_s
                and len(self._frames) < self.HARD_CAPACITY
            ):
                return None  # latency rather than a pair too wide for the VO
            skipped, carried = self._frames[i]
            del self._frames[i]
            successor, before = self._frames[i]  # the pair of the next frame now spans the skipped ones
            self._frames[i] = (successor, before + carried + 1)
            return skipped

    def _skip_candidate(self) -> tuple[int, float]:
        """The queued frame (not the newest) whose removal leaves the shortest gap, the oldest of equal
        ones, and that gap: its neighbours are the previous queued frame (or the one taken last) and the
        next one."""
        stamps = [f.stamp_s for f, _ in self._frames]
        previous = [self._taken_s, *stamps[:-1]]
        i = min(range(len(stamps) - 1), key=lambda j: stamps[j + 1] - previous[j])
        return i, stamps[i + 1] - previous[i]

    def take(self) -> tuple[F, int] | None:
        """The oldest queued frame and how many frames apart it is from the one taken before (1: the next
        frame, 3: two skipped between), or None."""
        with self._lock:
            if not self._frames:
                return None
            frame, skipped_before = self._frames.popleft()
            self._taken_s = frame.stamp_s
            return frame, skipped_before + 1

    def depth(self) -> int:
        return len(self._frames)


class HeldSamples(Generic[S]):
    """Samples drained from the sensor queue and held, in stamp order, until the frame queued before them
    is pushed (the filter refuses a frame older than what it already applied). Bounded: past ``capacity``
    the oldest are released at once. For the estimator thread only."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise InputError(f"the held samples need a capacity of at least 1, got {capacity}")
        self.capacity = capacity
        self._samples: list[S] = []

    def __len__(self) -> int:
        return len(self._samples)

    def add(self, samples: list[S]) -> list[S]:
        """Hold ``samples``; returns the oldest held ones beyond the capacity (to apply now)."""
        if not samples:
            return []
        self._samples.extend(samples)
        self._samples.sort(key=lambda m: m.stamp_s)
        return self._release(len(self._samples) - self.capacity)

    def until(self, stamp_s: float) -> list[S]:
        """Release the held samples stamped up to ``stamp_s`` (all: ``math.inf``), in stamp order."""
        return self._release(bisect.bisect_right(self._samples, stamp_s, key=lambda m: m.stamp_s))

    def _release(self, n: int) -> list[S]:
        if n <= 0:
            return []
        out = self._samples[:n]
        del self._samples[:n]
        return out


@dataclass(frozen=True)
class Turn(Generic[S, F]):
    """One turn of the estimator thread: ``samples`` to apply in this order, then ``frame`` (if any), taken
    ``spacing`` frames after the one taken before it."""

    samples: list[S] = field(default_factory=list)
    frame: F | None = None
    spacing: int = 0


class Backlog(Generic[S, F]):
    """The sensor samples (:attr:`samples`, a :class:`~services.runtime.handoff.WorkQueue`: its ``offer``
    refuses beyond ``sample_capacity``), the frames (:class:`SpacedFrameQueue`) and the samples held back for
    them (:class:`HeldSamples`). Callbacks offer, the estimator thread takes turns (:meth:`next`); a frame
    wakes it through the sample queue."""

    def __init__(
        self, sample_capacity: int, frame_capacity: int, max_pair_s: float, max_backlog_s: float
    ) -> None:
        if sample_capacity < 1:
            raise InputError(f"the sample queue needs a capacity of at least 1, got {sample_capacity}")
        self.sample_capacity = sample_capacity
        #: the sensor samples' queue: callbacks offer to it (False when full: the caller counts the refusal)
        self.samples: WorkQueue[S] = WorkQueue(sample_capacity)
        self.frames: SpacedFrameQueue[F] = SpacedFrameQueue(frame_capacity, max_pair_s, max_backlog_s)
        self.held: HeldSamples[S] = HeldSamples(sample_capacity)

    def offer_frame(self, frame: F) -> F | None:
        """Queue a frame (callbacks); the frame skipped to make room, if any."""
        skipped = self.frames.offer(frame)
        self.samples.wake()
        return skipped

    def next(self, timeout_s: float) -> Turn[S, F]:
        """The queued samples, then the oldest queued frame with the samples before it (waits up to
        ``timeout_s`` for a sample when nothing is queued). A frame still queued after the samples are drained
        arrived before the samples newer than it: they are held until it is applied; a frame arriving later is
        newer than them all. Samples beyond the held capacity are released at once (the oldest)."""
        idle = not self.held and self.frames.depth() == 0
        if idle:
            self.samples.wait(timeout_s)
        drained = self.samples.drain()
        first, rest = (drained[:1], drained[1:]) if idle else ([], drained)
        released = self.held.add(first) + self.held.add(rest)
        taken = self.frames.take()
        if taken is None:
            return Turn(released + self.held.until(math.inf))
        frame, spacing = taken
        return Turn(released + self.held.until(frame.stamp_s), frame, spacing)

    def depths(self) -> dict[str, int]:
        return {"samples": self.samples.depth(), "frames": self.frames.depth(), "held": len(self.held)}
