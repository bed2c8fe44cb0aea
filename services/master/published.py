"""The yaw published for a master's UAV, kept only from sessions that led the UAV (a take-over's start).

A standby continues the yaw from the last published one. Without access control anybody may publish on the
yaw key, so a yaw counts only when the session that sent it is trusted: this master's own session, or one
that answered as the elected active master. Zenoh 1.10 tells a Python subscriber only the source a sample
*declares* (``source_info``, which the master sets on every yaw it puts); the session id of the active
master comes from the ``replier_id`` of its health reply, which the zenoh runtime of the replying session
sets (the Python API cannot choose it). So a yaw is refused when it declares no source or a session that
never led; one declared by a session not resolved yet waits until its session is resolved (or dropped).

This raises the bar, it does not authenticate: a forger that copies the active master's declared source
(it sees it on every yaw) is believed. Only the secure profile (only ``master.{uav}`` may put the yaw)
authenticates the sender.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass
from enum import Enum
from typing import TypeVar

from common.provenance import Provenance
from common.wire.messages import Frame, YawEstimate
from common.yaw.tracker import FrameYaw
from services.runtime.round import RoundReport

_K = TypeVar("_K")
#: the declared source of samples that declare none
ANONYMOUS = "anonymous"


def session_of(source: str | None) -> str:
    """The zenoh session id of a declared source ``zid/eid`` (:data:`ANONYMOUS` when none is declared)."""
    return source.split("/")[0] if source else ANONYMOUS


class PublishVerdict(Enum):
    TRUSTED = "trusted"
    #: from a session not resolved yet: kept, counted only once its session is resolved as a leader
    PENDING = "pending"
    REFUSED = "refused"


@dataclass(frozen=True)
class YawAnchor:
    """The yaw a new stream continues from (a new rig or epoch, a take-over), with its variance."""

    yaw_rad: float = 0.0
    yaw_variance_rad2: float = 0.0


@dataclass(frozen=True)
class PublishedYaw:
    seq: int
    stamp_s: float
    yaw_rad: float
    session: str
    yaw_variance_rad2: float = 0.0

    @classmethod
    def of(cls, estimate: YawEstimate, session: str) -> PublishedYaw:
        return cls(estimate.seq, estimate.stamp_s, estimate.yaw_rad, session, estimate.yaw_variance_rad2)

    @property
    def anchor(self) -> YawAnchor:
        return YawAnchor(self.yaw_rad, self.yaw_variance_rad2)


class PublishedLedger:
    """Published yaws by seq (the newest ``capacity``) from trusted sessions, and, apart (so that a flood
    cannot push trusted ones out), the newest ``capacity`` of sessions not resolved yet.

    ``leaders_resolved`` (of :meth:`record`): whether every alive leader's session is known; while one is
    not, a yaw of an unknown session is kept as pending (it may be that leader's), otherwise it is refused.
    """

    def __init__(self, own_session: str, capacity: int, max_sessions: int = 16) -> None:
        self.own_session = own_session
        self.capacity = capacity
        self.max_sessions = max_sessions
        #: sessions that answered as an elected active master (newest last); this master's own is trusted too
        self.trusted: list[str] = []
        self._yaw: OrderedDict[int, tuple[int, PublishedYaw]] = OrderedDict()
        self._pending: OrderedDict[tuple[int, str], tuple[int, PublishedYaw]] = OrderedDict()
        self._arrivals = 0
        self.refused = 0

    def trust(self, session: str) -> None:
        """``session`` answered as the active master: its yaws (pending and future) count."""
        if session in self.trusted:
            self.trusted.remove(session)
        self.trusted.append(session)
        del self.trusted[: -self.max_sessions]
        for key in [k for k in self._pending if k[1] == session]:
            arrival, yaw = self._pending.pop(key)
            self._keep(self._yaw, yaw.seq, (arrival, yaw))

    def is_trusted(self, session: str) -> bool:
        return session == self.own_session or session in self.trusted

    def record(self, yaw: PublishedYaw, leaders_resolved: bool) -> PublishVerdict:
        """Keep ``yaw`` as trusted or pending, or refuse it (counted)."""
        self._arrivals += 1
        if self.is_trusted(yaw.session):
            self._keep(self._yaw, yaw.seq, (self._arrivals, yaw))
            return PublishVerdict.TRUSTED
        if yaw.session == ANONYMOUS or leaders_resolved:
            self.refused += 1
            return PublishVerdict.REFUSED
        self._keep(self._pending, (yaw.seq, yaw.session), (self._arrivals, yaw))
        return PublishVerdict.PENDING

    def _keep(
        self, kept: OrderedDict[_K, tuple[int, PublishedYaw]], key: _K, item: tuple[int, PublishedYaw]
    ) -> None:
        kept[key] = item
        kept.move_to_end(key)
        while len(kept) > self.capacity:
            kept.popitem(last=False)

    def trusted_yaws(self) -> dict[int, PublishedYaw]:
        """seq -> the trusted yaws kept."""
        return {s: y for s, (_, y) in self._yaw.items()}

    def newest_trusted(self) -> PublishedYaw | None:
        """The last trusted yaw to arrive, None when there is none."""
        if not self._yaw:
            return None
        return max(self._yaw.values(), key=lambda item: item[0])[1]


def take_over_anchor(
    recent: list[tuple[int, Frame]], published: dict[int, PublishedYaw]
) -> tuple[int, Frame, YawAnchor] | None:
    """Where a take-over continues: the newest kept ``(epoch, frame)`` whose yaw was published (the same seq
    and stamp), with that yaw and its variance; None when no kept frame was."""
    for epoch, frame in reversed(recent):
        known = published.get(frame.seq)
        if known is not None and known.stamp_s == frame.stamp_s:
            return epoch, frame, known.anchor
    return None


def initial_estimate(
    uav: str,
    seq: int,
    stamp_s: float,
    anchor: YawAnchor,
    t0_perf_s: float,
    dropped: int,
) -> YawEstimate:
    """The estimate of a stream's first frame (a new epoch or rig): the yaw it continues from with that yaw's
    variance, nothing measured yet (``INITIAL``, low confidence)."""
    return YawEstimate(
        uav=uav,
        seq=seq,
        stamp_s=stamp_s,
        delta_yaw_rad=0.0,
        yaw_rad=anchor.yaw_rad,
        yaw_variance_rad2=anchor.yaw_variance_rad2,
        inlier_count=0,
        patch_count=0,
        confidence=0.0,
        low_confidence=True,
        method="initial",
        provenance=Provenance.INITIAL,
        timings_ms={"total": (time.perf_counter() - t0_perf_s) * 1e3},
        dropped_frames=dropped,
    )


def measured_estimate(
    uav: str,
    frame: Frame,
    core: FrameYaw,
    timings_ms: dict[str, float],
    members: dict[str, int],
    report: RoundReport | None,
    dropped: int,
) -> YawEstimate:
    """The estimate of a measured frame: the core's yaw (``core``), how it was measured and by whom
    (``report``: the frame's round; None: computed here after the round failed)."""
    return YawEstimate(
        uav=uav,
        seq=frame.seq,
        stamp_s=frame.stamp_s,
        delta_yaw_rad=float(core.delta_yaw_rad),
        yaw_rad=float(core.yaw_rad),
        inlier_count=int(core.inlier_count),
        patch_count=int(core.patch_count),
        confidence=float(core.confidence) if math.isfinite(core.confidence) else 0.0,
        low_confidence=bool(core.low_confidence),
        method=core.method.name.lower(),
        timings_ms=timings_ms,
        members=members,
        speeds_patches_s=dict(report.speeds) if report else {},
        dropped_frames=dropped,
        redispatched=report.redispatched if report else 0,
        provenance=core.provenance,
        yaw_variance_rad2=core.yaw_variance_rad2,
        delta_variance_rad2=core.delta_variance_rad2,
        measured_delta_rad=core.measured_delta_rad if math.isfinite(core.measured_delta_rad) else None,
    )
