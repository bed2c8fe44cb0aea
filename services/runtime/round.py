"""One frame's round of a :class:`~services.runtime.scatter.Scatter`: what it sends and does (:class:`Round`),
the events its requests produce (:class:`ReplyArrived`, :class:`QueryDone`, :class:`MemberLeft`) and why a
request fails (:class:`FailureReason`)."""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import zenoh

from common.dispatch import SELF, Plan
from common.wire import frame_codec
from common.wire.messages import PatchResult, YawJobSettings
from common.yaw import PatchGrid
from common.yaw.grid import crop_mosaic
from common.yaw.measurement import PatchMeasurement
from services.runtime.results import measurement_of

if TYPE_CHECKING:
    from services.runtime.scatter import Scatter

logger = logging.getLogger(__name__)


class FailureReason(StrEnum):
    """Why a request to a member failed (its share is then re-dispatched within the round)."""

    DEADLINE_MISSED = "deadline missed"
    LEFT = "left (liveliness lost)"
    NO_REPLY = "no reply"
    ERROR_REPLY = "error reply"
    EMPTY_REPLY = "empty reply"
    MALFORMED_REPLY = "malformed reply"
    MISMATCHED_REPLY = "mismatched reply"


@dataclass(frozen=True)
class Failure:
    """A failed request: the reason, and what the member or zenoh said."""

    reason: FailureReason
    detail: str = ""

    def __str__(self) -> str:
        return f"{self.reason.value}: {self.detail}" if self.detail else self.reason.value


class ReplyArrived(NamedTuple):
    """A reply to request ``rid`` of round ``epoch`` (zenoh's thread stamped its arrival)."""

    rid: int
    epoch: int
    reply: Any
    arrived_perf_s: float


class QueryDone(NamedTuple):
    """Zenoh finished request ``rid`` of round ``epoch`` (after its replies, or without any)."""

    rid: int
    epoch: int


class MemberLeft(NamedTuple):
    """A member's liveliness token vanished."""

    member: str


RoundEvent = ReplyArrived | QueryDone | MemberLeft


class JobBand(NamedTuple):
    """A share's new-frame pixels as one band (:class:`~common.wire.messages.PatchJob`): its bytes in
    ``encoding``, its (rows, cols) and each index's crop corner ``[row, col]`` in it."""

    data: np.ndarray
    shape: tuple[int, int]
    encoding: str
    corners: np.ndarray


def job_band(
    grid: PatchGrid,
    level_u8: np.ndarray,
    encoding: str,
    indices: np.ndarray,
    quality: int = frame_codec.DEFAULT_JPEG_QUALITY,
) -> JobBand | None:
    """The pixels of patches ``indices`` of a frame's level image as one image (bound with
    ``functools.partial`` it is :attr:`FrameWork.band`) in ``encoding`` (:mod:`common.wire.frame_codec`).
    ``mono8``: the band bounding them (:meth:`PatchGrid.band_level`), or None where their crops are fewer
    pixels (they travel as they are). A compressing encoding: their strips packed (the zeros between cost
    next to nothing; :meth:`PatchGrid.packed_level`), or their crops side by side
    (:func:`~common.yaw.grid.crop_mosaic`) where the strips hold more pixels than the crops. ``quality``:
    JPEG's (``jpeg`` alone; bound by keyword with the encoding)."""
    if not len(indices) or (encoding == "mono8" and not grid.patches_overlap):
        return None  # patches apart (the defaults): their crops are always the fewer bytes
    if encoding == "mono8":
        got = grid.band_level(level_u8, indices)
        if got is None:
            return None
        image, corners = got
    else:
        image, corners, pixels = grid.packed_level(level_u8, indices)
        if pixels >= len(indices) * grid.patch_size_px**2:
            image, corners = crop_mosaic(grid.crop_level(level_u8, indices))
    data = np.frombuffer(frame_codec.encode(image, encoding, quality), np.uint8)
    return JobBand(data, (int(image.shape[0]), int(image.shape[1])), encoding, corners)


@dataclass
class FrameWork:
    """What a scatter round needs about the frame: crops by index, and how to compute a share locally."""

    stream: str
    seq: int
    prev_seq: int
    settings: YawJobSettings
    budget_s: float
    #: level crops (n, s, s) of the new frame for indices
    crops: Callable[[np.ndarray], np.ndarray]
    #: level crops of the previous frame for indices
    prev_crops: Callable[[np.ndarray], np.ndarray]
    #: compute a share in-process: (indices, moved indices) -> measurement
    compute_self: Callable[[np.ndarray, np.ndarray], PatchMeasurement]
    #: the new frame's pixels for indices as one band, or None where their crops are fewer bytes (no
    #: callable: always crops)
    band: Callable[[np.ndarray], JobBand | None] | None = None


@dataclass
class RoundReport:
    """Outcome of one frame: the measured parts and who computed what."""

    parts: list[PatchMeasurement] = field(default_factory=list)
    #: who computed each of ``parts`` (same order)
    owners: list[str] = field(default_factory=list)
    members: dict[str, int] = field(default_factory=dict)
    speeds: dict[str, float] = field(default_factory=dict)
    redispatched: int = 0
    failures: list[str] = field(default_factory=list)
    self_s: float = 0.0


@dataclass
class Request:
    member: str
    indices: np.ndarray
    sent_monotonic_s: float
    #: when the request counts as failed (absolute, ``time.monotonic()``)
    deadline_monotonic_s: float
    #: start of the round for the first plan's shares, the send time for re-dispatched ones (monotonic)
    start_monotonic_s: float = 0.0
    result: PatchResult | None = None
    failure: Failure | None = None
    #: a solo request's own reply channel (None: replies arrive through the callbacks' event queue)
    replies: Any = None
    cancel: zenoh.CancellationToken | None = None
    #: set (under the scatter's lock) before a solo request is cancelled because its member left: the
    #: token's own ``is_cancelled`` may still read False when the closed channel wakes the round thread
    left: bool = False


class Round:
    """One frame's round: the requests in flight, the shares computed here, failures re-dispatched."""

    def __init__(self, scatter: Scatter, work: FrameWork) -> None:
        self.scatter = scatter
        self.dispatcher = scatter.dispatcher
        self.counters = scatter.counters
        self.work = work
        self.report = RoundReport()
        self.pending: dict[int, Request] = {}
        #: shares the dispatcher computes itself: (indices, moved indices)
        self.self_queue: list[tuple[np.ndarray, np.ndarray]] = []
        self.failed: set[str] = set()
        self.start_monotonic_s = time.monotonic()

    def dispatch(self, plan: Plan, start_monotonic_s: float | None = None) -> None:
        """Send each member of ``plan`` its share (a lone one blocks on its own channel); queue SELF's."""
        work = self.work
        alone = not self.pending and len(plan.assignment) == 1 and SELF not in plan.assignment
        for member, indices in plan.assignment.items():
            moved = plan.moved[member]
            if member == SELF:
                if (
                    start_monotonic_s is not None
                    and len(plan.assignment) > 1
                    and not self.dispatcher.settings.self_compute
                ):
                    # a dispatcher that only dispatches computes what a trust cap cut from a fast member
                    # and the others would have finished last with (common.dispatch.plan.capped_counts)
                    self.counters.inc("cap_overflow_patches", int(indices.size))
                self.self_queue.append((indices, moved))
                continue
            timeout_s = self.dispatcher.timeout_s(member, int(indices.size), work.budget_s)
            now = time.monotonic()
            request = Request(member, indices, now, now + timeout_s, start_monotonic_s or now)
            try:
                rid = self.scatter._send(work, member, indices, moved, timeout_s, request if alone else None)
            except Exception as exc:  # session closing, encode failure: compute it here instead
                self.counters.inc("send_failures")
                logger.warning("cannot send share to %s: %s", member, exc)
                self.self_queue.append((indices, indices))
                continue
            self.pending[rid] = request

    def fail(self, rid: int, failure: Failure) -> None:
        """Request ``rid`` failed: pause its member and re-dispatch its share within this round."""
        request = self.pending.pop(rid)
        self.failed.add(request.member)
        self.report.failures.append(f"{request.member}: {failure}")
        self.report.redispatched += 1
        self.counters.inc("redispatched")
        self.counters.inc("redispatched_patches", int(request.indices.size))
        if failure.reason is FailureReason.DEADLINE_MISSED:
            self.counters.inc("deadline_misses")
        now = time.monotonic()
        waited = now - request.sent_monotonic_s if failure.reason is FailureReason.DEADLINE_MISSED else None
        pause = self.dispatcher.record_failure(request.member, now, int(request.indices.size), waited)
        logger.warning(
            "frame %d: %s failed (%s); re-dispatching %d patches, member paused %.1f s",
            self.work.seq,
            request.member,
            failure,
            request.indices.size,
            pause,
        )
        self.dispatch(
            self.dispatcher.redistribute(request.indices, self.failed, time.monotonic(), self.work.prev_seq)
        )

    def succeed(self, rid: int, arrived_monotonic_s: float | None = None) -> None:
        """Request ``rid`` was answered (its reply arrived at ``arrived_monotonic_s``; None: now): record the
        member's speed and take its measurement."""
        request = self.pending.pop(rid)
        result = request.result
        assert result is not None
        report = self.report
        # the reply's arrival, not when this thread got to it: while the dispatcher computes its own share, a
        # member's reply waits, and a round trip read after that share made the member look as slow as it
        arrived = time.monotonic() if arrived_monotonic_s is None else arrived_monotonic_s
        elapsed = arrived - request.start_monotonic_s
        # the member's own speed measure (a worker: its compute time; a foreman: the sum of its workers'
        # speeds); the dispatcher's speed_source decides whether it or patches / elapsed balances
        reported = sum(result.speeds.values()) if result.speeds else None
        self.dispatcher.record_success(request.member, self.work.seq, request.indices, elapsed, reported)
        report.parts.append(measurement_of(result))
        report.owners.append(request.member)
        n = int(request.indices.size)
        report.members[request.member] = report.members.get(request.member, 0) + n
        for sub, count in result.members.items():
            if sub != request.member:
                key = f"{request.member}>{sub}"
                report.members[key] = report.members.get(key, 0) + count
        for sub, value in result.speeds.items():
            if sub != request.member:
                report.speeds[f"{request.member}>{sub}"] = value
        speed = self.dispatcher.speed(request.member)
        if speed is not None:
            report.speeds[request.member] = speed

    def compute_own_shares(self) -> None:
        """Compute the queued ``SELF`` shares in this thread (the members work meanwhile)."""
        report = self.report
        while self.self_queue:
            indices, moved = self.self_queue.pop(0)
            t0 = time.perf_counter()
            measurement = self.work.compute_self(indices, moved)
            elapsed = time.perf_counter() - t0
            report.self_s += elapsed
            report.parts.append(measurement)
            report.owners.append(SELF)
            report.members[SELF] = report.members.get(SELF, 0) + int(indices.size)
            self.dispatcher.record_success(SELF, self.work.seq, indices, elapsed)
            self_speed = self.dispatcher.speed(SELF)
            if self_speed is not None:
                report.speeds[SELF] = self_speed

    def wait_once(self) -> None:
        """Wait for what happens next to a request in flight (a reply, its end, a deadline, a leave)."""
        if len(self.pending) == 1:
            rid, request = next(iter(self.pending.items()))
            if request.replies is not None:
                failure = self.scatter._await_solo(request, self.work)
                if failure is None:
                    self.succeed(rid)
                else:
                    self.fail(rid, failure)
                return
        timeout = max(0.0, min(r.deadline_monotonic_s for r in self.pending.values()) - time.monotonic())
        try:
            event = self.scatter._events.get(timeout=timeout)
        except queue.Empty:
            now = time.monotonic()
            for late in [r for r, q in self.pending.items() if q.deadline_monotonic_s <= now]:
                self.fail(late, Failure(FailureReason.DEADLINE_MISSED))
            return
        self.on_event(event)

    def on_event(self, event: RoundEvent) -> None:
        epoch = self.scatter._epoch
        if isinstance(event, MemberLeft):
            for gone in [r for r, q in self.pending.items() if q.member == event.member]:
                self.fail(gone, Failure(FailureReason.LEFT))
            return
        if event.rid not in self.pending or event.epoch != epoch:
            return  # late answer of a request already re-dispatched, or of an older frame
        request = self.pending[event.rid]
        if isinstance(event, ReplyArrived):
            t_woke = time.perf_counter()
            arrived_monotonic_s = time.monotonic() - (t_woke - event.arrived_perf_s)
            self.scatter._accept(request, event.reply, self.work)
            self.counters.time_ms("wake", (t_woke - event.arrived_perf_s) * 1e3)
            self.counters.time_ms("accept", (time.perf_counter() - t_woke) * 1e3)
            if request.result is not None:
                self.succeed(event.rid, arrived_monotonic_s)
            elif request.failure is not None:
                self.fail(event.rid, request.failure)
        else:  # QueryDone: no (usable) reply came
            self.fail(event.rid, request.failure or Failure(FailureReason.NO_REPLY))
