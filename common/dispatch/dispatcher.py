"""The one dispatcher: which member computes which patches of a frame (pure, no I/O).

Used twice: the master splits a frame among foremen (or workers, for the master-worker baseline) and
each foreman splits its block among its workers. The zenoh I/O lives in the services; this class only
decides:

- membership (:meth:`Dispatcher.join` / :meth:`Dispatcher.leave`, from liveliness) and suspension of a
  member that missed a deadline (:meth:`Dispatcher.record_failure`, exponential back-off);
- shares: ``balance=none`` -> proportional to each member's declared capacity (e.g. its worker count, so
  every compute unit gets the same number of patches); ``balance=time`` -> proportional to an exponential
  moving average of each member's measured patches per second (a joiner starts at the mean speed);
- assignment in runs: each member's share is one run of neighbouring patch indices, in the members'
  order, so it travels as one band of the frame where patches overlap; while the shares hold a member
  keeps its indices (its cached spectra stay valid), a change moves only indices at the runs' ends, and
  :attr:`Plan.moved` tells which indices a member does not hold for the previous frame (it must be sent
  the previous patches too);
- re-dispatch of a failed member's indices among the others, within the same frame
  (:meth:`Dispatcher.redistribute`), falling back to the dispatcher itself (``SELF``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.dispatch.plan import IndexArray, Memo, Plan, capped_counts, missing, run_plan
from common.dispatch.settings import Balance, DispatchSettings, SpeedSource
from common.dispatch.trust import TrustMonitor, doubling_suspension_s
from common.errors import CapatazError, InputError

#: Name of the dispatcher itself as a member (the master or foreman computing a share).
SELF = "self"


class DispatchError(CapatazError):
    """A dispatch decision is impossible (unknown member, bad indices)."""


@dataclass
class _Member:
    capacity: float = 1.0
    speed_ema: float | None = None
    failures: int = 0
    suspended_until_s: float = -math.inf
    held_seq: int = -2
    held: frozenset[int] = field(default_factory=frozenset)


class Dispatcher:
    """Membership, shares, assignment in runs and re-dispatch decisions for ``n_patches`` patches."""

    def __init__(self, settings: DispatchSettings, n_patches: int) -> None:
        if n_patches < 1:
            raise InputError(f"n_patches must be >= 1, got {n_patches}")
        self.settings = settings
        self.n_patches = n_patches
        self._members: dict[str, _Member] = {SELF: _Member(capacity=settings.self_capacity)}
        #: the last plan's (members, targets, indices) and assignment (:data:`~common.dispatch.plan.Memo`)
        self._memo: Memo | None = None
        #: every patch index, built on the first plan of all patches (a foreman plans only the indices it is
        #: given: a list of 2**16 indices made each of its per-stream dispatchers 2.4 MB)
        self._all: list[int] | None = None
        self.last_plan: Plan | None = None
        #: defence in depth (common.dispatch.trust), and the frame's (size, patches per member) for its caps
        self.trust: TrustMonitor | None = None
        self._frame: tuple[int, dict[str, int]] = (0, {})

    # -- membership -------------------------------------------------------------------------------------
    def join(self, member: str, capacity: float = 1.0) -> None:
        """Add a member (idempotent; a re-join resets its failures but keeps its speed)."""
        if member == SELF:
            raise DispatchError(f"{SELF!r} is reserved for the dispatcher itself")
        if capacity <= 0 or not math.isfinite(capacity):
            raise InputError(f"capacity must be positive, got {capacity}")
        state = self._members.get(member)
        if state is None:
            self._members[member] = _Member(capacity=capacity)
        else:
            state.capacity = capacity
            state.failures = 0
            state.suspended_until_s = -math.inf

    def set_capacity(self, member: str, capacity: float) -> None:
        """Change a member's declared capacity (its weight under ``balance=none``)."""
        if capacity <= 0 or not math.isfinite(capacity):
            raise InputError(f"capacity must be positive, got {capacity}")
        if member in self._members:
            self._members[member].capacity = capacity

    def leave(self, member: str) -> None:
        """Remove a member; its indices become free (assigned to others in the next plan)."""
        if member == SELF:
            return
        self._members.pop(member, None)
        self._memo = None

    @property
    def members(self) -> tuple[str, ...]:
        """Remote members (without ``SELF``), sorted."""
        return tuple(sorted(m for m in self._members if m != SELF))

    def active(self, now_s: float, answered_only: bool = False) -> list[str]:
        """Remote members not suspended, plus ``SELF`` when configured or alone (see TrustMonitor.screen)."""
        remote = [m for m in self.members if self._members[m].suspended_until_s <= now_s]
        if self.trust is not None:  # suspended for inconsistent results; new members tried a few at a time
            remote = self.trust.screen(remote, {m for m in remote if not self.speed(m)}, now_s, answered_only)
        if self.settings.self_compute or not remote:
            return [*remote, SELF]
        return remote

    def speed(self, member: str) -> float | None:
        state = self._members.get(member)
        return None if state is None else state.speed_ema

    def speeds(self) -> dict[str, float]:
        return {m: s.speed_ema for m, s in self._members.items() if s.speed_ema is not None}

    # -- shares -----------------------------------------------------------------------------------------
    def _counts(self, members: list[str], total: int, now_s: float) -> tuple[list[str], list[int]]:
        """Counts per member of a re-dispatch under the trust share caps (counting the frame's earlier
        shares): :func:`~common.dispatch.plan.capped_counts`."""
        trust = None
        if self.trust is not None:
            trust = self.trust.view([m for m in members if m != SELF], set(), now_s)
        frame, load = self._frame if self._frame[0] else (total, {})
        by_time = self.settings.balance is Balance.TIME
        return capped_counts(
            members, self._members, by_time, total, trust, frame, load, len(self.members), SELF,
            self.settings.overflow_slack,
        )  # fmt: skip

    def plan(self, seq: int, prev_seq: int, now_s: float, indices: npt.ArrayLike | None = None) -> Plan:
        """Assign patches ``indices`` (default: all) of frame ``seq`` (vs ``prev_seq``) to active members
        (:func:`~common.dispatch.plan.run_plan`): the trust monitor is consulted once, then the plan is
        computed in one call, and nothing of this module runs after them."""
        if indices is None:
            if self._all is None:
                self._all = list(range(self.n_patches))
            todo = self._all
        else:
            todo = self._check_indices(indices)
        joined = self.members
        remote = [m for m in joined if self._members[m].suspended_until_s <= now_s]
        trust = None
        if self.trust is not None:  # suspended for inconsistent results; new members tried a few at a time
            trust = self.trust.view(remote, {m for m in remote if not self.speed(m)}, now_s)
        planned = run_plan(
            seq, prev_seq, todo, remote, self._members, trust, self.settings.balance is Balance.TIME,
            self.settings.self_compute, self._memo, len(joined), SELF,
            self.settings.overflow_slack, self.settings.move_deadband,
        )  # fmt: skip
        self._memo, self._frame, self.last_plan = planned.memo, planned.frame, planned.plan
        return planned.plan

    def _check_indices(self, indices: npt.ArrayLike) -> list[int]:
        arr = np.asarray(indices)
        if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
            raise DispatchError(
                f"indices must be a 1-D integer array, got shape {arr.shape} dtype {arr.dtype}"
            )
        values = sorted(arr.tolist())
        if values and (values[0] < 0 or values[-1] >= self.n_patches):
            raise DispatchError(f"indices out of range 0..{self.n_patches - 1}")
        if len(set(values)) != len(values):
            raise DispatchError("indices must be distinct")
        return values

    def redistribute(self, indices: npt.ArrayLike, exclude: set[str], now_s: float, prev_seq: int) -> Plan:
        """Split a failed share among the active members not in ``exclude`` (else ``SELF``), same frame.

        Each receiver then holds the spectra of what it computed (a later plan's :attr:`Plan.moved` knows).
        """
        idx = np.array(self._check_indices(indices), dtype=np.int32)
        members = [m for m in self.active(now_s, answered_only=True) if m not in exclude] or [SELF]
        members, counts = self._counts(members, int(idx.size), now_s)
        assignment: dict[str, IndexArray] = {}
        moved: dict[str, IndexArray] = {}
        start = 0
        for m, n in zip(members, counts, strict=True):
            if n == 0:
                continue
            part = idx[start : start + n]
            start += n
            self._memo = None
            assignment[m] = part
            moved[m] = missing(self._members[m], part, prev_seq)
            self._frame[1][m] = self._frame[1].get(m, 0) + int(n)
        seq = self.last_plan.seq if self.last_plan else 0
        return Plan(seq=seq, prev_seq=prev_seq, assignment=assignment, moved=moved)

    # -- outcomes ---------------------------------------------------------------------------------------
    def record_success(
        self,
        member: str,
        seq: int,
        indices: npt.ArrayLike,
        elapsed_s: float,
        reported_speed: float | None = None,
    ) -> None:
        """A member computed ``indices`` of frame ``seq`` in ``elapsed_s``: update its speed and history.

        ``reported_speed`` (patches/s) is the member's own measure when it reports one (a worker's compute
        time, a foreman's sum of its workers' speeds). Which measure balances is
        :attr:`DispatchSettings.speed_source`: ``reported`` uses it when given, ``round-trip`` (the default,
        see :class:`SpeedSource` for why) always ``len(indices) / elapsed_s``.
        """
        state = self._members.get(member)
        if state is None:
            return  # left meanwhile
        idx = frozenset(np.asarray(indices).ravel().tolist())
        if state.held_seq == seq:
            state.held = state.held | idx  # a second share in the same frame (re-dispatch)
        else:
            state.held_seq, state.held = seq, idx
        state.failures = 0
        state.suspended_until_s = -math.inf
        speed = reported_speed if self.settings.speed_source is SpeedSource.REPORTED else None
        if speed is None and idx and elapsed_s > 0:
            speed = len(idx) / elapsed_s
        if speed is not None and speed > 0 and math.isfinite(speed):
            a = self.settings.ema_alpha
            state.speed_ema = speed if state.speed_ema is None else a * speed + (1 - a) * state.speed_ema

    def record_failure(
        self, member: str, now_s: float, n_patches: int = 0, waited_s: float | None = None
    ) -> float:
        """A member missed its deadline or answered with an error: suspend it; returns the suspension (s).

        When it missed a deadline of ``waited_s`` for ``n_patches``, its speed is at most
        ``n_patches / waited_s``: the moving average is capped there, so that it comes back with a
        smaller share and a longer deadline instead of failing the same way again.
        """
        state = self._members.get(member)
        if state is None or member == SELF:
            return 0.0
        state.failures += 1
        state.held_seq, state.held = -2, frozenset()
        if n_patches > 0 and waited_s is not None and waited_s > 0:
            bound = n_patches / waited_s
            state.speed_ema = bound if state.speed_ema is None else min(state.speed_ema, bound)
        cfg = self.settings
        pause = doubling_suspension_s(cfg.suspend_s, cfg.max_suspend_s, state.failures - 1)
        state.suspended_until_s = now_s + pause
        self._memo = None
        return pause

    def forget_history(self, member: str) -> None:
        """The member lost its cache (e.g. it restarted): send it previous patches again."""
        state = self._members.get(member)
        if state is not None:
            state.held_seq, state.held = -2, frozenset()

    def timeout_s(self, member: str, n_patches: int, budget_s: float) -> float:
        """How long a request of ``n_patches`` may take (a duration): the whole budget while the member's
        speed is unknown, else ``deadline_factor`` times the expected time (at least ``min_deadline_s``, at
        most the budget)."""
        speed = self.speed(member)
        if not speed:
            return budget_s
        expected = n_patches / speed
        return min(budget_s, max(self.settings.min_deadline_s, self.settings.deadline_factor * expected))
