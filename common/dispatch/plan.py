"""One frame's assignment (:class:`Plan`): the apportionment of patches to members by weight
(:func:`largest_remainder`, Hamilton's method), held and capped by the trust monitor's view
(:func:`capped_counts`), and the assignment in runs (:func:`run_plan`). Pure: the dispatcher
(:mod:`common.dispatch.dispatcher`) holds the state and calls this module once per plan."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from common.errors import InputError

IndexArray = npt.NDArray[np.int32]


@dataclass(frozen=True)
class Plan:
    """Assignment of one frame: member -> sorted patch indices, and the indices it lacks history for."""

    seq: int
    prev_seq: int
    assignment: dict[str, IndexArray]
    moved: dict[str, IndexArray]

    def shares(self) -> dict[str, float]:
        total = sum(len(v) for v in self.assignment.values())
        return {m: len(v) / total for m, v in self.assignment.items()} if total else {}


def largest_remainder(weights: npt.ArrayLike, total: int) -> npt.NDArray[np.int64]:
    """Integer counts proportional to ``weights`` summing to ``total`` (Hamilton's method)."""
    return np.array(apportion(np.asarray(weights, dtype=np.float64).tolist(), total), dtype=np.int64)


def apportion(weights: list[float], total: int) -> list[int]:
    """:func:`largest_remainder` on a plain list: a plan has a handful of members, where Python floats
    are several times cheaper than numpy's per-call overhead (this runs for every frame, twice per path).
    Ties go to the earlier member."""
    if (
        not isinstance(weights, list)
        or not weights
        or any(not (isinstance(w, float) and math.isfinite(w) and w >= 0) for w in weights)
        or sum(weights) <= 0
    ):
        raise InputError(
            f"weights must be a non-empty 1-D array of finite non-negative values, got {weights}"
        )
    if total < 0:
        raise InputError(f"total must be >= 0, got {total}")
    if len(weights) == 1:
        return [total]
    weight_sum = sum(weights)
    exact = [w / weight_sum * total for w in weights]
    counts = [math.floor(e) for e in exact]
    remainder = total - sum(counts)
    order = sorted(range(len(weights)), key=lambda i: (-(exact[i] - counts[i]), i))
    for i in order[:remainder]:
        counts[i] += 1
    return counts


# -- one frame's plan, from the dispatcher's state and the trust monitor's view (one call per plan) --------


class MemberState(Protocol):
    """What a plan reads of a member's state (the dispatcher's record of it)."""

    capacity: float
    speed_ema: float | None
    held_seq: int
    held: frozenset[int]


class TrustView(Protocol):
    """What a plan takes from the trust monitor (:meth:`~common.dispatch.trust.TrustMonitor.view`)."""

    @property
    def enabled(self) -> bool: ...
    @property
    def kept(self) -> tuple[str, ...]: ...
    @property
    def credited(self) -> frozenset[str]: ...
    @property
    def share_limits(self) -> Mapping[str, float]: ...


#: the last plan's (members, targets, indices) and assignment: the steady state repeats it exactly (same
#: members, same shares), so it is reused until one of them changes
MemoKey = tuple[tuple[str, ...], tuple[int, ...], tuple[int, ...]]
Memo = tuple[MemoKey, dict[str, IndexArray]]


@dataclass(frozen=True)
class Planned:
    """A plan and what the dispatcher keeps of it: the memo and the frame's (size, patches per member) for
    the share caps of a re-dispatch."""

    plan: Plan
    memo: Memo
    frame: tuple[int, dict[str, int]]


def balance_weights(states: Sequence[MemberState], by_time: bool) -> tuple[list[float], list[float], bool]:
    """Each member's balancing weight (its capacity, or its measured speed when ``by_time``: a member without
    measurement starts at the mean speed per unit of capacity of the measured ones), the capacities and
    whether any speed was measured."""
    capacity = [float(s.capacity) for s in states]
    if not by_time:
        return capacity, capacity, False
    speeds = [s.speed_ema if s.speed_ema is not None and s.speed_ema > 0 else None for s in states]
    known = [v / c for v, c in zip(speeds, capacity, strict=True) if v is not None]
    if not known:
        return capacity, capacity, False
    per_capacity = sum(known) / len(known)
    w = [float(v) if v is not None else per_capacity * c for v, c in zip(speeds, capacity, strict=True)]
    return w, capacity, True


def capped_counts(
    members: list[str],
    states: Mapping[str, MemberState],
    by_time: bool,
    total: int,
    trust: TrustView | None,
    frame_total: int,
    load: Mapping[str, int],
    joined: int,
    own: str,
    slack: float,
) -> tuple[list[str], list[int]]:
    """Counts per member: apportioned by weight, the speed of members without credit held
    (:func:`capped_weights`), and the trust share caps (from two ``joined`` remote members on, each holds at
    most its share limit of ``frame_total``, ``load`` being what it holds already).

    What a cap cuts goes to the members with room, the one that would finish first taking each patch
    (:func:`cap_counts` by weight), but none beyond ``1 + slack`` times its own balanced count: a slow
    member (a thin link, a slow CPU) is not handed the fast one's excess, which would make it the frame's
    last. The rest goes to ``own``, the dispatcher itself, appended when absent. With two remote members
    and a cap of a half, this is what lets the shares move away from a slow one at all (they stayed at
    half each before)."""
    weights, capacity, measured = balance_weights([states[m] for m in members], by_time)
    if measured and trust is not None and trust.enabled:
        held = capped_weights(
            dict(zip(members, weights, strict=True)),
            dict(zip(members, capacity, strict=True)),
            {m: m == own or m in trust.credited for m in members},
        )
        weights = [held[m] for m in members]
    counts = apportion(weights, total)
    if trust is None or not trust.enabled or joined < 2:
        return members, counts
    limits: list[int | None] = [
        None if m == own else max(0, math.floor(trust.share_limits[m] * frame_total) - load.get(m, 0))
        for m in members
    ]
    if all(limit is None or c <= limit for c, limit in zip(counts, limits, strict=True)):
        return members, counts
    weight_sum = sum(weights)
    for i, limit in enumerate(limits):  # no member takes overflow beyond 1 + slack times its balanced count
        if limit is not None:
            balanced = weights[i] / weight_sum * total if weight_sum > 0 else 0.0
            limits[i] = min(limit, max(counts[i], math.floor((1.0 + slack) * balanced)))
    if own not in members:
        members, counts, limits = [*members, own], [*counts, 0], [*limits, None]
        weights = [*weights, 0.0]
    return members, cap_counts(counts, limits, weights)


def missing(state: MemberState, indices: IndexArray, prev_seq: int) -> IndexArray:
    """The ``indices`` a member does not hold for frame ``prev_seq`` (it must be sent those patches too)."""
    if state.held_seq != prev_seq:
        return indices.copy()
    held = state.held
    wanted = indices.tolist()
    if held.issuperset(wanted):
        return indices[:0]  # the sticky steady state: it holds them all
    return np.array([i for i in wanted if i not in held], dtype=np.int32)


def within_deadband(previous: MemoKey, new: MemoKey, deadband: float) -> bool:
    """Whether plan ``new`` (members, counts, patches) is ``previous`` but for counts that each differ by at
    most ``deadband`` of the patches (rounded, at least one patch; ``deadband`` 0: never). A member given
    its first patches, or none, always changes the plan (a member on trial gets one or two)."""
    (members0, counts0, todo0), (members1, counts1, todo1) = previous, new
    if deadband <= 0.0 or members0 != members1 or todo0 != todo1:
        return False
    limit = max(1, round(deadband * len(todo1)))
    pairs = list(zip(counts0, counts1, strict=True))
    return all(abs(a - b) <= limit and (a == 0) == (b == 0) for a, b in pairs)


def run_plan(
    seq: int,
    prev_seq: int,
    todo: list[int],
    remote: list[str],
    states: Mapping[str, MemberState],
    trust: TrustView | None,
    by_time: bool,
    self_compute: bool,
    memo: Memo | None,
    joined: int,
    own: str,
    slack: float,
    deadband: float = 0.0,
) -> Planned:
    """Frame ``seq``'s plan (vs ``prev_seq``) of the patches ``todo``: the ``remote`` members the trust
    monitor keeps (plus ``own`` when ``self_compute`` or alone) get counts by :func:`capped_counts`, each as
    one run of neighbouring indices of ``todo``, in the members' order.

    A run of neighbouring patches travels as one band of the frame where patches overlap (a quarter fewer
    bytes than its crops at 1920x1080 with 128 px patches; a fifth fewer compressed), and while the counts
    hold, the plan repeats exactly (the memo). When a count changes, only indices at the runs' ends move: a
    member is sent the previous patches of those (:attr:`Plan.moved`). Assigning moved indices lowest first
    instead kept every unchanged index with its member but scattered a share over the frame within a few
    frames, so that it always travelled as crops. Counts within ``deadband`` of the previous plan's
    (:func:`within_deadband`) keep the previous plan."""
    kept = remote if trust is None else list(trust.kept)
    members = [*kept, own] if self_compute or not kept else kept
    members, counts = capped_counts(
        members, states, by_time, len(todo), trust, len(todo), {}, joined, own, slack
    )
    key = (tuple(members), tuple(counts), tuple(todo))
    if memo is not None and memo[0] != key and within_deadband(memo[0], key, deadband):
        key = memo[0]  # the previous counts: a change this small is not worth the patches it would move
    if memo is not None and memo[0] == key:
        repeated = dict(memo[1])
        lacking = {m: missing(states[m], owned, prev_seq) for m, owned in repeated.items()}
        frame = (len(todo), {m: len(v) for m, v in repeated.items()})
        return Planned(Plan(seq, prev_seq, repeated, lacking), memo, frame)
    ordered = np.array(sorted(todo), dtype=np.int32)
    assignment: dict[str, IndexArray] = {}
    moved: dict[str, IndexArray] = {}
    start = 0
    for m, count in zip(members, counts, strict=True):
        if not count:
            continue
        indices = ordered[start : start + count]
        start += count
        indices.setflags(write=False)  # shared by the plans that repeat this one
        assignment[m] = indices
        moved[m] = missing(states[m], indices, prev_seq)
    frame = (len(todo), {m: len(v) for m, v in assignment.items()})
    return Planned(Plan(seq, prev_seq, assignment, moved), (key, assignment), frame)


def cap_counts(
    counts: Sequence[int], limits: Sequence[int | None], weights: Sequence[float] | None = None
) -> list[int]:
    """Move what exceeds each entry's limit to entries with room; the total is preserved.

    ``limits[i]`` None means uncapped. Overflow goes first to capped entries with room, one patch at a time
    to the one that would finish first with it (the lowest ``count / weight``; without ``weights``, the
    emptiest; ties to the earlier), then to the last uncapped entry (callers put the dispatcher itself
    there); with no uncapped entry, the last entry takes it.
    """
    if len(counts) != len(limits) or not counts or (weights is not None and len(weights) != len(counts)):
        raise InputError("counts, limits and weights must be non-empty and of equal length")
    if any(c < 0 for c in counts) or any(limit is not None and limit < 0 for limit in limits):
        raise InputError("counts and limits must be >= 0")
    speed = [1.0] * len(counts) if weights is None else [max(float(w), 1e-12) for w in weights]
    out = list(counts)
    overflow = 0
    for i, limit in enumerate(limits):
        if limit is not None and out[i] > limit:
            overflow += out[i] - limit
            out[i] = limit
    while overflow:
        room = [i for i, limit in enumerate(limits) if limit is not None and out[i] < limit]
        if not room:
            break
        i = min(room, key=lambda j: ((out[j] + 1) / speed[j], j))
        take = min(overflow, (limits[i] or 0) - out[i])
        # one at a time keeps the spread even among several entries with room
        take = 1 if len(room) > 1 else take
        out[i] += take
        overflow -= take
    if overflow:
        free = [i for i, limit in enumerate(limits) if limit is None]
        out[free[-1] if free else len(out) - 1] += overflow
    return out


def capped_weights(
    weights: Mapping[str, float], capacity: Mapping[str, float], credited: Mapping[str, bool]
) -> dict[str, float]:
    """Weights where a member without credit is held at the slowest per-capacity speed of all members.

    Its speed then buys it no more than its capacity share relative to the slowest member (what
    ``balance=none`` would give it); a credited member keeps its measured weight. A single fast liar
    cannot raise the reference (it is the minimum), and a slow member keeps its lower weight.
    """
    per_capacity = [w / capacity[m] for m, w in weights.items() if capacity.get(m, 0) > 0 and w > 0]
    if not per_capacity:
        return dict(weights)
    floor = min(per_capacity)
    return {m: w if credited.get(m, False) else min(w, floor * capacity[m]) for m, w in weights.items()}
