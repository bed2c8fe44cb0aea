"""The zenoh side of the one dispatcher: send each member its share of a frame, gather, re-dispatch.

Used by the master (members = foremen or workers) and by each foreman (members = its workers). The
decisions (who gets which patches, deadlines, suspensions) are the pure :class:`Dispatcher`'s; this
module only sends the queries, waits for replies or deadlines or liveliness losses, and asks the
dispatcher where a failed share goes, within the same frame. The dispatcher itself (``SELF``) computes
its share in the calling thread while the others work, and takes every share nobody else can.
"""

from __future__ import annotations

import argparse
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from common.dispatch import SELF, Balance, Dispatcher, Plan, SpeedSource
from common.messages import BlockJob, PatchJob, PatchResult, WireError, decode, encode, read_error_reply
from common.yaw.correlation import PatchMeasurement
from common.yaw.patchwork import PatchWorkError
from services.runtime.transport import Counters, zbytes

logger = logging.getLogger(__name__)

#: the error payload zenoh replies with when a query's timeout expires (zenoh 1.10)
ZENOH_TIMEOUT = b"Timeout"


@dataclass
class FrameWork:
    """What a scatter round needs about the frame: crops by index, and how to compute a share locally."""

    stream: str
    seq: int
    prev_seq: int
    settings: dict[str, Any]
    budget_s: float
    #: level crops (n, s, s) of the new frame for indices
    crops: Callable[[np.ndarray], np.ndarray]
    #: level crops of the previous frame for indices
    prev_crops: Callable[[np.ndarray], np.ndarray]
    #: compute a share in-process: (indices, moved indices) -> measurement
    compute_self: Callable[[np.ndarray, np.ndarray], PatchMeasurement]


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
class _Request:
    member: str
    indices: np.ndarray
    sent_s: float
    deadline_s: float
    #: start of the round for the first plan's shares, the send time for re-dispatched ones
    start_s: float = 0.0
    result: PatchResult | None = None
    error: str | None = None
    #: a solo request's own reply channel (None: replies arrive through the callbacks' event queue)
    replies: Any = None
    cancel: zenoh.CancellationToken | None = None


class Scatter:
    """Runs one frame's round of requests for a :class:`Dispatcher` over a zenoh session."""

    def __init__(
        self,
        session: zenoh.Session,
        dispatcher: Dispatcher,
        member_key: Callable[[str], str],
        job_type: type[PatchJob],
        result_type: type[PatchResult],
        counters: Counters,
    ) -> None:
        self.session = session
        self.dispatcher = dispatcher
        self.member_key = member_key
        self.job_type = job_type
        self.result_type = result_type
        self.counters = counters
        # SimpleQueue: unbounded but fed only by our own requests (<= 2 events each) and liveliness changes;
        # its put/get are C calls, cheaper than Queue's Condition on the reply path
        self._events: queue.SimpleQueue[tuple[str, int, Any]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._next_id = 0
        self._epoch = 0
        #: parsed key expressions of the members (a str would be parsed again for every request)
        self._keys: dict[str, zenoh.KeyExpr] = {}
        #: the solo request in flight (member, its cancellation), cancelled when that member leaves
        self._solo: tuple[str, zenoh.CancellationToken] | None = None

    # called from liveliness callbacks (any thread): never blocks
    def member_left(self, member: str) -> None:
        self._events.put(("left", -1, member))
        with self._lock:
            solo = self._solo
        if solo is not None and solo[0] == member:
            solo[1].cancel()  # the round thread blocked on its reply channel wakes at once

    def _send(
        self,
        work: FrameWork,
        member: str,
        indices: np.ndarray,
        moved: np.ndarray,
        budget_s: float,
        solo: _Request | None = None,
    ) -> int:
        """Send one share; a ``solo`` request (the only one in flight) gets its own reply channel."""
        with self._lock:
            rid = self._next_id
            self._next_id += 1
        crops = work.crops(indices)
        # nothing moved (the usual, sticky case): no previous crops to cut
        prev_crops = work.prev_crops(moved) if moved.size else crops[:0]
        # built from our own validated data: skip re-validation here, the receiver validates at its boundary
        job = self.job_type.model_construct(
            stream=work.stream,
            seq=work.seq,
            prev_seq=work.prev_seq,
            settings=work.settings,
            indices=indices.astype(np.int32, copy=False),
            crops=crops,
            prev_indices=moved.astype(np.int32, copy=False),
            prev_crops=prev_crops,
            budget_s=budget_s,
        )
        payload, attachment = encode(job)
        events = self._events
        epoch = self._epoch

        def on_reply(reply: zenoh.Reply) -> None:
            events.put(("reply", rid, (epoch, reply, time.perf_counter())))

        def on_done() -> None:
            events.put(("done", rid, epoch))

        key = self._keys.get(member)
        if key is None:
            key = self._keys[member] = zenoh.KeyExpr(self.member_key(member))
        if solo is not None:
            # Alone in flight: the round thread blocks on this query's own FIFO channel, zenoh's timeout is
            # the deadline (a "Timeout" error reply) and a member that leaves cancels it. No Python runs on
            # zenoh's thread and one hand-off is saved: 0.03-0.04 ms per 752x480 job round trip to a worker
            # (capataz bench cluster, "reply_handoff"). Several requests need the callbacks: they stamp each
            # reply's arrival, which round-trip balancing measures.
            solo.cancel = zenoh.CancellationToken()
            with self._lock:
                self._solo = (member, solo.cancel)
            solo.replies = self.session.get(
                key,
                zenoh.handlers.FifoChannel(2),
                payload=payload,
                attachment=attachment,
                timeout=budget_s,
                consolidation=zenoh.ConsolidationMode.NONE,
                congestion_control=zenoh.CongestionControl.BLOCK,
                cancellation_token=solo.cancel,
            )
        else:
            # indirect=False: the two callbacks only put into a queue, so they run on zenoh's own thread
            # instead of a Python thread per query (one thread hop less per reply; measured -0.3 ms per frame
            # on the master-foreman-worker path)
            self.session.get(
                key,
                zenoh.handlers.Callback(on_reply, on_done, indirect=False),
                payload=payload,
                attachment=attachment,
                timeout=budget_s + 0.5,
                consolidation=zenoh.ConsolidationMode.NONE,
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        self.counters.inc("requests_sent")
        self.counters.inc("patches_sent", int(indices.size))
        self.counters.inc("prev_patches_sent", int(moved.size))
        return rid

    def run(self, work: FrameWork, plan: Plan) -> RoundReport:
        """Send ``plan``'s shares, compute ``SELF``'s, re-dispatch failures; every index gets measured."""
        self._epoch += 1
        report = RoundReport()
        pending: dict[int, _Request] = {}
        self_queue: list[tuple[np.ndarray, np.ndarray]] = []
        failed: set[str] = set()

        round_start = time.monotonic()

        def dispatch(p: Plan, start_s: float | None = None) -> None:
            alone = not pending and len(p.assignment) == 1 and SELF not in p.assignment
            for member, indices in p.assignment.items():
                moved = p.moved[member]
                if member == SELF:
                    self_queue.append((indices, moved))
                    continue
                deadline = self.dispatcher.deadline_s(member, int(indices.size), work.budget_s)
                now = time.monotonic()
                request = _Request(member, indices, now, now + deadline, start_s or now)
                try:
                    rid = self._send(work, member, indices, moved, deadline, request if alone else None)
                except Exception as exc:  # session closing, encode failure: compute it here instead
                    self.counters.inc("send_failures")
                    logger.warning("cannot send share to %s: %s", member, exc)
                    self_queue.append((indices, indices))
                    continue
                pending[rid] = request

        def fail(rid: int, why: str) -> None:
            request = pending.pop(rid)
            failed.add(request.member)
            report.failures.append(f"{request.member}: {why}")
            report.redispatched += 1
            self.counters.inc("redispatched")
            self.counters.inc("redispatched_patches", int(request.indices.size))
            now = time.monotonic()
            waited = now - request.sent_s if why == "deadline missed" else None
            pause = self.dispatcher.record_failure(request.member, now, int(request.indices.size), waited)
            logger.warning(
                "frame %d: %s failed (%s); re-dispatching %d patches, member paused %.1f s",
                work.seq,
                request.member,
                why,
                request.indices.size,
                pause,
            )
            dispatch(self.dispatcher.redistribute(request.indices, failed, time.monotonic(), work.prev_seq))

        def succeed(rid: int) -> None:
            request = pending.pop(rid)
            result = request.result
            assert result is not None
            elapsed = time.monotonic() - request.start_s
            # reported: the member's own speed measure (a worker: its compute time; a foreman: the sum of its
            # workers' speeds), independent of transport; round-trip: patches / elapsed
            reported = (
                sum(result.speeds.values())
                if result.speeds and self.dispatcher.settings.speed_source is SpeedSource.REPORTED
                else None
            )
            self.dispatcher.record_success(request.member, work.seq, request.indices, elapsed, reported)
            report.parts.append(_measurement(result))
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

        # liveliness losses queued before this round are in the plan already (the caller applied membership)
        while not self._events.empty():
            self._events.get_nowait()
        t_send = time.perf_counter()
        dispatch(plan, round_start)
        self.counters.time_ms("send", (time.perf_counter() - t_send) * 1e3)
        while pending or self_queue:
            while self_queue:
                indices, moved = self_queue.pop(0)
                t0 = time.perf_counter()
                measurement = work.compute_self(indices, moved)
                elapsed = time.perf_counter() - t0
                report.self_s += elapsed
                report.parts.append(measurement)
                report.owners.append(SELF)
                report.members[SELF] = report.members.get(SELF, 0) + int(indices.size)
                self.dispatcher.record_success(SELF, work.seq, indices, elapsed)
                self_speed = self.dispatcher.speed(SELF)
                if self_speed is not None:
                    report.speeds[SELF] = self_speed
            if not pending:
                break
            if len(pending) == 1:
                rid, request = next(iter(pending.items()))
                if request.replies is not None:
                    why = self._await_solo(request, work)
                    if why is None:
                        succeed(rid)
                    else:
                        if why == "deadline missed":
                            self.counters.inc("deadline_misses")
                        fail(rid, why)
                    continue
            timeout = max(0.0, min(r.deadline_s for r in pending.values()) - time.monotonic())
            try:
                kind, rid, value = self._events.get(timeout=timeout)
            except queue.Empty:
                now = time.monotonic()
                for late in [r for r, q in pending.items() if q.deadline_s <= now]:
                    self.counters.inc("deadline_misses")
                    fail(late, "deadline missed")
                continue
            if kind == "left":
                for gone in [r for r, q in pending.items() if q.member == value]:
                    fail(gone, "left (liveliness lost)")
                continue
            if rid not in pending:
                continue  # late answer of a request already re-dispatched, or of an older frame
            if kind == "reply":
                epoch, reply, t_reply = value
                if epoch != self._epoch:
                    continue
                t_woke = time.perf_counter()
                self._accept(pending[rid], reply, work)
                self.counters.time_ms("wake", (t_woke - t_reply) * 1e3)
                self.counters.time_ms("accept", (time.perf_counter() - t_woke) * 1e3)
                request = pending[rid]
                if request.result is not None:
                    succeed(rid)
                elif request.error is not None:
                    fail(rid, request.error)
            elif kind == "done" and value == self._epoch:
                request = pending[rid]
                fail(rid, request.error or "no reply")
        return report

    def _await_solo(self, request: _Request, work: FrameWork) -> str | None:
        """Block on a solo request's reply channel; None when it succeeded, else why it failed."""
        try:
            reply = request.replies.recv()
        except zenoh.ZError:  # closed without a reply: cancelled (the member left) or nobody answered
            cancelled = request.cancel is not None and request.cancel.is_cancelled
            return "left (liveliness lost)" if cancelled else "no reply"
        finally:
            with self._lock:
                self._solo = None
        if reply.err is not None and zbytes(reply.err.payload) == ZENOH_TIMEOUT:
            return "deadline missed"
        t_woke = time.perf_counter()
        self._accept(request, reply, work)
        self.counters.time_ms("accept", (time.perf_counter() - t_woke) * 1e3)
        if request.result is not None:
            return None
        return request.error or "no reply"

    def _accept(self, request: _Request, reply: zenoh.Reply, work: FrameWork) -> None:
        if reply.err is not None:
            request.error = "error reply: " + read_error_reply(reply.err.payload.to_bytes())
            self.counters.inc("error_replies")
            return
        sample = reply.ok
        if sample is None:
            request.error = "empty reply"
            return
        try:
            result = decode(zbytes(sample.payload), zbytes(sample.attachment), self.result_type)
        except WireError as exc:
            self.counters.inc("malformed_replies")
            request.error = f"malformed reply: {exc}"
            return
        if (
            result.seq != work.seq
            or result.stream != work.stream
            or not np.array_equal(result.indices, request.indices)
        ):
            request.error = f"reply for frame {result.seq}/{result.stream} does not match the request"
            self.counters.inc("mismatched_replies")
            return
        request.result = result


def _measurement(result: PatchResult) -> PatchMeasurement:
    return PatchMeasurement(
        indices=np.asarray(result.indices, dtype=np.intp),
        shift_px=np.asarray(result.shift_px, dtype=np.float64),
        confidence=np.asarray(result.confidence, dtype=np.float64),
        peak=np.asarray(result.peak, dtype=np.float64),
        valid=np.asarray(result.valid, dtype=np.bool_),
    )


def result_from_measurement(
    result_type: type[PatchResult],
    job: PatchJob | BlockJob,
    member: str,
    measurement: PatchMeasurement,
    compute_s: float,
    members: dict[str, int],
    speeds: dict[str, float],
) -> PatchResult:
    """The reply message for a job from its measurement (shared by workers and foremen).

    Built without re-validation (the arrays come from the core with the wire dtypes); the receiver
    validates at its boundary.
    """
    return result_type.model_construct(
        stream=job.stream,
        seq=job.seq,
        prev_seq=job.prev_seq,
        member=member,
        indices=np.asarray(measurement.indices, dtype=np.int32),
        shift_px=np.asarray(measurement.shift_px, dtype=np.float64).reshape(-1, 2),
        confidence=np.asarray(measurement.confidence, dtype=np.float64),
        peak=np.asarray(measurement.peak, dtype=np.float64),
        valid=np.asarray(measurement.valid, dtype=np.bool_),
        compute_s=compute_s,
        members=members,
        speeds=speeds,
    )


__all__ = ["FrameWork", "PatchWorkError", "RoundReport", "Scatter", "result_from_measurement"]


def add_dispatch_arguments(parser: argparse.ArgumentParser, compute_help: str) -> None:
    """The dispatcher's options, shared by the master and the foreman."""
    parser.add_argument(
        "--balance", choices=[b.value for b in Balance], default="time", help="share balancing"
    )
    parser.add_argument("--compute", action=argparse.BooleanOptionalAction, default=False, help=compute_help)
    parser.add_argument("--min-deadline-ms", type=float, default=300.0, help="smallest per-request deadline")
    parser.add_argument(
        "--speed",
        choices=[v.value for v in SpeedSource],
        default=SpeedSource.ROUND_TRIP.value,
        help="speed measure for time balancing: members' own figures, or round-trip patches/s",
    )
