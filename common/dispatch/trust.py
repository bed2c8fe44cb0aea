"""Defence in depth for dispatchers: members whose results disagree with the robust fit lose their work.

A member (foreman or worker) is only trusted as far as its results are consistent with everybody's:

- **consistency**: after each frame, each member's valid patches are counted as inliers or outliers of
  the robust fit over the whole frame (or block). :class:`TrustMonitor` keeps a sliding window per
  member; a member whose outlier rate exceeds the other members' by more than ``outlier_margin`` (over
  at least ``min_patches`` of its patches) is **suspended** for ``suspend_s`` and reported
  (:class:`Suspension`). The suspension is by member name and survives leave/re-join (liveliness churn).
- **share cap** (:func:`~common.dispatch.plan.cap_counts`, with each member's limit from
  :meth:`TrustMonitor.view`): from two joined remote members on, none gets more than
  ``max_share`` of a frame, and ``probation_share`` until it has earned credit (the rest goes to the
  others as far as their speed allows, else to the dispatcher itself:
  :func:`~common.dispatch.plan.capped_counts`), so no single member holds the majority the robust fit
  follows, not even while the others are suspended.
- **earned speed**: under time balancing a member's measured speed only buys a share above its
  capacity-proportional one once it has ``earn_frames`` consistent frames (:meth:`TrustMonitor.credited`);
  a member that answers implausibly fast with wrong shifts stays at its fair share and is then suspended.

Pure: counts in, decisions out; the services feed it and apply its decisions to the :class:`Dispatcher`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded
from common.errors import InputError


def doubling_suspension_s(first_s: float, max_s: float, earlier: int) -> float:
    """A suspension that doubles with each ``earlier`` one, capped: ``min(max_s, first_s * 2**earlier)`` (s)
    (a dispatcher's after missed deadlines, the trust monitor's after inconsistent results)."""
    return float(min(max_s, first_s * 2.0**earlier))


@dataclass(frozen=True)
class TrustSettings(Bounded):
    """Thresholds of :class:`TrustMonitor` and the share cap."""

    #: largest share of a frame one remote member may get (applied from two joined remote members on, so
    #: it holds while the others are suspended); 1 = off
    max_share: float = bounded(0.5, gt=0.0, le=1.0)
    #: the same for a member that has not earned credit yet (new, or inconsistent lately) while others
    #: have: the dispatcher computes the rest itself, so a newcomer alone never outvotes it
    probation_share: float = bounded(1.0 / 3.0, gt=0.0)
    #: frames of history per member
    window: int = bounded(30, ge=1)
    #: a member is judged once its window holds this many valid patches
    min_patches: int = bounded(40, ge=1)
    #: suspended when its outlier rate exceeds the others' by more than this
    outlier_margin: float = bounded(0.35, gt=0.0, lt=1.0)
    #: how long a suspension lasts (s); it doubles for each repeated suspension
    suspend_s: float = bounded(30.0, gt=0.0)
    max_suspend_s: float = bounded(600.0, gt=0.0)
    #: consistent frames before a member's speed may buy more than its capacity share
    earn_frames: int = bounded(10, ge=0)
    #: members that never answered yet which get work in one frame (a flood of fake tokens is tried a few
    #: at a time; each that fails is paused by the dispatcher)
    max_untested: int = bounded(4, ge=1)
    enabled: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.probation_share > self.max_share:
            raise InputError(
                f"need probation_share <= max_share, got {self.probation_share} > {self.max_share}"
            )
        if self.max_suspend_s < self.suspend_s:
            raise InputError(f"need suspend_s <= max_suspend_s, got {self.suspend_s} > {self.max_suspend_s}")


@dataclass(frozen=True)
class MemberOutcome:
    """One member's valid patches in one frame and how many of them were outliers of the fit."""

    member: str
    valid: int
    outliers: int

    def __post_init__(self) -> None:
        if self.valid < 0 or not 0 <= self.outliers <= self.valid:
            raise InputError(f"need 0 <= outliers <= valid, got {self.outliers}/{self.valid}")


@dataclass(frozen=True)
class Suspension:
    """A member suspended for inconsistent results (what the service logs, counts and reports)."""

    member: str
    outlier_rate: float
    others_rate: float
    patches: int
    until_s: float
    reason: str


@dataclass
class _Record:
    frames: deque[tuple[int, int]] = field(default_factory=deque)
    consistent_frames: int = 0
    suspended_until_s: float = -math.inf
    suspensions: int = 0


def outcomes_of_fit(
    owners: Sequence[str],
    parts_indices: Sequence[npt.ArrayLike],
    indices: npt.ArrayLike,
    valid: npt.ArrayLike,
    inlier_of_valid: npt.ArrayLike,
) -> list[MemberOutcome]:
    """Per member: valid patches and outliers among them, from a frame's fit.

    ``owners[k]`` computed ``parts_indices[k]``; ``indices``/``valid`` are the merged measurement (ascending
    indices) and ``inlier_of_valid`` the fit's inlier flags over its valid patches, in the same order.
    """
    idx = np.asarray(indices, dtype=np.int64)
    ok = np.asarray(valid, dtype=bool)
    inl = np.asarray(inlier_of_valid, dtype=bool)
    if ok.shape != idx.shape or inl.size != int(ok.sum()) or len(owners) != len(parts_indices):
        raise InputError("indices, valid and inlier flags do not match")
    outlier = np.zeros(idx.shape, dtype=bool)
    outlier[np.flatnonzero(ok)] = ~inl
    totals: dict[str, list[int]] = {}
    for owner, part in zip(owners, parts_indices, strict=True):
        rows = np.searchsorted(idx, np.asarray(part, dtype=np.int64))
        if rows.size and (rows.max() >= idx.size or not np.array_equal(idx[rows], np.asarray(part))):
            raise InputError(f"{owner}'s indices are not in the measurement")
        entry = totals.setdefault(owner, [0, 0])
        entry[0] += int(ok[rows].sum())
        entry[1] += int(outlier[rows].sum())
    return [MemberOutcome(m, v, o) for m, (v, o) in totals.items()]


@dataclass(frozen=True)
class TrustView:
    """What one plan takes from the monitor (:meth:`TrustMonitor.view`): the members it keeps, those with
    credit (their speed may buy more than their capacity share) and each member's share limit."""

    enabled: bool
    kept: tuple[str, ...]
    credited: frozenset[str]
    share_limits: Mapping[str, float]


class TrustMonitor:
    """Per-member consistency history, suspensions and speed credit (see the module docstring)."""

    def __init__(self, settings: TrustSettings | None = None) -> None:
        self.settings = settings or TrustSettings()
        self._records: dict[str, _Record] = {}
        self.verdicts: list[Suspension] = []

    def _record(self, member: str) -> _Record:
        return self._records.setdefault(member, _Record())

    def observe(self, outcomes: Sequence[MemberOutcome], now_s: float) -> list[Suspension]:
        """Add one frame's outcomes (only frames with two or more members are informative); returns the
        members suspended now."""
        s = self.settings
        if not s.enabled or len(outcomes) < 2:
            return []
        for o in outcomes:
            rec = self._record(o.member)
            rec.frames.append((o.valid, o.outliers))
            while len(rec.frames) > s.window:
                rec.frames.popleft()
        new: list[Suspension] = []
        for o in outcomes:
            rate, patches = self.outlier_rate(o.member)
            others = self._others_rate(o.member, [x.member for x in outcomes])
            rec = self._records[o.member]
            inconsistent = patches >= s.min_patches and rate - others > s.outlier_margin
            frame_bad = o.valid > 0 and o.outliers / o.valid - others > s.outlier_margin
            rec.consistent_frames = 0 if (frame_bad or inconsistent) else rec.consistent_frames + 1
            if inconsistent and rec.suspended_until_s <= now_s:
                pause = doubling_suspension_s(s.suspend_s, s.max_suspend_s, rec.suspensions)
                rec.suspensions += 1
                rec.suspended_until_s = now_s + pause
                rec.frames.clear()
                verdict = Suspension(
                    o.member,
                    rate,
                    others,
                    patches,
                    rec.suspended_until_s,
                    f"outlier rate {rate:.0%} vs {others:.0%} of the others over {patches} patches",
                )
                new.append(verdict)
        self.verdicts.extend(new)
        return new

    def suspend(self, member: str, until_s: float) -> None:
        """Suspend ``member`` until ``until_s`` for a reason of the caller's (e.g. liveliness churn)."""
        rec = self._record(member)
        rec.suspended_until_s = max(rec.suspended_until_s, until_s)

    def outlier_rate(self, member: str) -> tuple[float, int]:
        """Outlier rate over the member's window and the number of valid patches in it."""
        rec = self._records.get(member)
        if rec is None:
            return 0.0, 0
        valid = sum(v for v, _ in rec.frames)
        outliers = sum(o for _, o in rec.frames)
        return (outliers / valid if valid else 0.0), valid

    def _others_rate(self, member: str, present: Sequence[str]) -> float:
        valid = outliers = 0
        for other in present:
            if other == member:
                continue
            rec = self._records.get(other)
            if rec is None:
                continue
            valid += sum(v for v, _ in rec.frames)
            outliers += sum(o for _, o in rec.frames)
        return outliers / valid if valid else 0.0

    def suspended(self, now_s: float) -> frozenset[str]:
        return frozenset(m for m, r in self._records.items() if r.suspended_until_s > now_s)

    def credited(self, member: str) -> bool:
        """Whether the member's speed may buy it more than its capacity share."""
        if self.settings.earn_frames == 0:
            return True
        rec = self._records.get(member)
        return rec is not None and rec.consistent_frames >= self.settings.earn_frames

    def share_limit(self, member: str) -> float:
        """The largest share of a frame ``member`` may get now: ``probation_share`` while it has no credit
        and others have (a newcomer next to proven members), else ``max_share``."""
        if self.credited(member) or not any(self.credited(m) for m in self._records):
            return self.settings.max_share
        return self.settings.probation_share

    def screen(
        self, members: Sequence[str], untested: set[str], now_s: float, answered_only: bool = False
    ) -> list[str]:
        """``members`` without the suspended ones, and with at most ``max_untested`` of the ``untested``
        ones (members that never answered yet; the first in order), none with ``answered_only``."""
        suspended = self.suspended(now_s)
        kept = [m for m in members if m not in suspended]
        fresh = sorted(m for m in kept if m in untested)
        if not self.settings.enabled or (len(fresh) <= self.settings.max_untested and not answered_only):
            return kept
        allowed = set() if answered_only else set(fresh[: self.settings.max_untested])
        return [m for m in kept if m not in untested or m in allowed]

    def view(
        self, members: Sequence[str], untested: set[str], now_s: float, answered_only: bool = False
    ) -> TrustView:
        """Everything a plan takes from the monitor, in one call: the members :meth:`screen` keeps, which of
        ``members`` are :meth:`credited` and the :meth:`share_limit` of each."""
        kept = self.screen(members, untested, now_s, answered_only)
        credited = frozenset(m for m in members if self.credited(m))
        limits = {m: self.share_limit(m) for m in members}
        return TrustView(self.settings.enabled, tuple(kept), credited, limits)

    def report(self) -> dict[str, float]:
        """Outlier rate per member (for stats)."""
        return {m: self.outlier_rate(m)[0] for m in self._records}
