"""A turning pair's second pass across members: transient jobs (:class:`~common.wire.jobs.PatchJob`, nothing
kept), each part sent to its member at once and gathered within one deadline. A part that fails comes back as
None and its sender measures it itself (:func:`common.yaw.patchwork.measure_crops`), so a frame never waits
on more than the deadline nor loses its refinement.

Unlike a frame's first pass (:class:`~services.runtime.scatter.Scatter`) nothing here is planned or balanced:
the parts go where the caller says (a master: to the members that measured those patches; a foreman: spread
over its workers), and no speed or share is learnt from them.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from common.wire.codec import decode, encode, read_error_reply
from common.wire.messages import PatchJob, PatchResult
from common.wire.schema import WireError
from common.yaw.measurement import PatchMeasurement
from services.runtime.counters import Counters
from services.runtime.results import job_of, measurement_of
from services.runtime.round import FrameWork
from services.runtime.transport import reply_channel, zbytes

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TransientPart:
    """One member's part: its key and the job (``transient`` set)."""

    member: str
    key: str
    job: PatchJob


#: a part on its way, with its reply channel (None: it could not be sent)
Sent = tuple[TransientPart, Any]


def send_parts(session: zenoh.Session, parts: Sequence[TransientPart], timeout_s: float) -> list[Sent]:
    """Send every part at once (each with its own bounded reply channel; zenoh ends it at ``timeout_s``)."""
    sent: list[Sent] = []
    for part in parts:
        try:
            replies = reply_channel(session, part.key, *encode(part.job), timeout_s)
        except zenoh.ZError as exc:  # the session is closing
            logger.warning("cannot send the refinement's part to %s: %s", part.member, exc)
            replies = None
        sent.append((part, replies))
    return sent


def gather(
    sent: Sequence[Sent], result_type: type[PatchResult], counters: Counters
) -> list[PatchMeasurement | None]:
    """Each part's measurement, or None where its member failed it (one warning line and
    ``refine_failures`` each); waits at most the parts' deadline (they run at once)."""
    out: list[PatchMeasurement | None] = []
    for part, replies in sent:
        failure, measurement = _reply_of(part.job, replies, result_type)
        if measurement is None:
            counters.inc("refine_failures")
            logger.warning(
                "frame %d: the refinement's part on %s failed (%s); measuring it here",
                part.job.seq,
                part.member,
                failure,
            )
        out.append(measurement)
    return out


def _reply_of(
    job: PatchJob, replies: Any, result_type: type[PatchResult]
) -> tuple[str, PatchMeasurement | None]:
    if replies is None:
        return "not sent", None
    try:
        reply = replies.recv()
    except zenoh.ZError:
        return "no reply", None
    if reply.err is not None:
        return f"error reply: {read_error_reply(reply.err.payload.to_bytes())}", None
    if reply.ok is None:
        return "empty reply", None
    try:
        result = decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), result_type)
    except WireError as exc:
        return f"malformed reply: {exc}", None
    if (
        result.seq != job.seq
        or result.stream != job.stream
        or not np.array_equal(result.indices, job.indices)
    ):
        return "mismatched reply", None
    return "", measurement_of(result)


def transient_job(
    job_type: type[PatchJob],
    of: PatchJob | FrameWork,
    indices: np.ndarray,
    crops_u8: np.ndarray,
    prev_crops_u8: np.ndarray | None,
    budget_s: float,
) -> PatchJob:
    """A transient job of patches ``indices`` of the frames ``of`` names (stream, frames, yaw settings): their
    turned-back crops and their previous crops (None: the member holds them, a foreman)."""
    prev_indices, prev = indices, prev_crops_u8
    if prev is None:  # the member holds them: none go
        prev_indices, prev = indices[:0], np.zeros((0, *crops_u8.shape[1:]), np.uint8)
    return job_of(job_type, of, indices, crops_u8, prev_indices, prev, budget_s, transient=True)


__all__ = ["Sent", "TransientPart", "gather", "send_parts", "transient_job"]
