"""The zenoh side of the one dispatcher: send each member its share of a frame, gather, re-dispatch.

Used by the master (members = foremen or workers) and by each foreman (members = its workers). The
decisions (who gets which patches, timeouts, suspensions, speeds) are the pure :class:`Dispatcher`'s; this
module only sends the queries, waits for replies or deadlines or liveliness losses, and asks the
dispatcher where a failed share goes, within the same frame. The dispatcher itself (``SELF``) computes
its share in the calling thread while the others work, and takes every share nobody else can.

A frame is one :class:`~services.runtime.round.Round`: its requests in flight, the shares computed here,
and what happened to each request, as typed events and failures with a ``FailureReason``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from common.dispatch import Dispatcher, Plan
from common.wire.codec import decode, encode, read_error_reply
from common.wire.jobs import band_decode_pixels
from common.wire.messages import PatchJob, PatchResult
from common.wire.schema import MAX_JOB_PIXELS, WireError
from services.runtime.counters import Counters
from services.runtime.results import job_of
from services.runtime.round import (
    Failure,
    FailureReason,
    FrameWork,
    MemberLeft,
    QueryDone,
    ReplyArrived,
    Request,
    Round,
    RoundEvent,
    RoundReport,
)
from services.runtime.transport import reply_channel, zbytes

logger = logging.getLogger(__name__)

#: the error payload zenoh replies with when a query's timeout expires (zenoh 1.10)
ZENOH_TIMEOUT = b"Timeout"


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
        self._events: queue.SimpleQueue[RoundEvent] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._next_id = 0
        self._epoch = 0
        #: parsed key expressions of the members (a str would be parsed again for every request)
        self._keys: dict[str, zenoh.KeyExpr] = {}
        #: the solo request in flight, cancelled when its member leaves
        self._solo: Request | None = None

    # called from liveliness callbacks (any thread): never blocks
    def member_left(self, member: str) -> None:
        self._events.put(MemberLeft(member))
        with self._lock:
            solo = self._solo
            if solo is None or solo.member != member or solo.cancel is None:
                return
            solo.left = True  # before the cancel: the woken round thread reads it, not the token's state
        solo.cancel.cancel()  # the round thread blocked on its reply channel wakes at once

    def _send(
        self,
        work: FrameWork,
        member: str,
        indices: np.ndarray,
        moved: np.ndarray,
        budget_s: float,
        solo: Request | None = None,
    ) -> int:
        """Send one share; a ``solo`` request (the only one in flight) gets its own reply channel."""
        with self._lock:
            rid = self._next_id
            self._next_id += 1
        band = work.band(indices) if work.band is not None else None
        side = int(work.settings.patch_size_px)
        if (
            band is not None
            and band_decode_pixels(band.data.size, band.shape, (indices.size + moved.size) * side * side)
            > MAX_JOB_PIXELS
        ):
            band = None  # the member would refuse it (what decoding holds): the crops go as they are
        pixels: dict[str, Any] = {}
        if band is None:
            crops = work.crops(indices)
        else:  # the share's pixels as one image, fewer bytes than its crops
            crops = np.zeros((0, side, side), np.uint8)
            pixels = dict(band=band.data, band_shape=band.shape, band_encoding=band.encoding,
                          corners=band.corners.astype(np.int32, copy=False))  # fmt: skip
            self.counters.inc("bands_sent")
        # nothing moved (the usual, sticky case): no previous crops to cut
        prev_crops = work.prev_crops(moved) if moved.size else crops[:0]
        job = job_of(self.job_type, work, indices, crops, moved, prev_crops, budget_s, **pixels)
        payload, attachment = encode(job)
        events = self._events
        epoch = self._epoch

        def on_reply(reply: zenoh.Reply) -> None:
            events.put(ReplyArrived(rid, epoch, reply, time.perf_counter()))

        def on_done() -> None:
            events.put(QueryDone(rid, epoch))

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
                self._solo = solo
            solo.replies = reply_channel(self.session, key, payload, attachment, budget_s, solo.cancel)
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
        round_ = Round(self, work)
        # liveliness losses queued before this round are in the plan already (the caller applied membership)
        while not self._events.empty():
            self._events.get_nowait()
        t_send = time.perf_counter()
        round_.dispatch(plan, round_.start_monotonic_s)
        self.counters.time_ms("send", (time.perf_counter() - t_send) * 1e3)
        while round_.pending or round_.self_queue:
            round_.compute_own_shares()
            if not round_.pending:
                break
            round_.wait_once()
        return round_.report

    def _await_solo(self, request: Request, work: FrameWork) -> Failure | None:
        """Block on a solo request's reply channel; None when it succeeded, else why it failed."""
        try:
            reply = request.replies.recv()
        except zenoh.ZError:  # closed without a reply: cancelled (the member left) or nobody answered
            with self._lock:
                left = request.left
            return Failure(FailureReason.LEFT if left else FailureReason.NO_REPLY)
        finally:
            with self._lock:
                self._solo = None
        if reply.err is not None and zbytes(reply.err.payload) == ZENOH_TIMEOUT:
            return Failure(FailureReason.DEADLINE_MISSED)
        t_woke = time.perf_counter()
        self._accept(request, reply, work)
        self.counters.time_ms("accept", (time.perf_counter() - t_woke) * 1e3)
        if request.result is not None:
            return None
        return request.failure or Failure(FailureReason.NO_REPLY)

    def _accept(self, request: Request, reply: zenoh.Reply, work: FrameWork) -> None:
        if reply.err is not None:
            request.failure = Failure(
                FailureReason.ERROR_REPLY, read_error_reply(reply.err.payload.to_bytes())
            )
            self.counters.inc("error_replies")
            return
        sample = reply.ok
        if sample is None:
            request.failure = Failure(FailureReason.EMPTY_REPLY)
            return
        try:
            result = decode(zbytes(sample.payload), zbytes(sample.attachment), self.result_type)
        except WireError as exc:
            self.counters.inc("malformed_replies")
            request.failure = Failure(FailureReason.MALFORMED_REPLY, str(exc))
            return
        if (
            result.seq != work.seq
            or result.stream != work.stream
            or not np.array_equal(result.indices, request.indices)
        ):
            detail = f"reply for frame {result.seq}/{result.stream} does not match the request"
            request.failure = Failure(FailureReason.MISMATCHED_REPLY, detail)
            self.counters.inc("mismatched_replies")
            return
        request.result = result


__all__ = ["Scatter"]
