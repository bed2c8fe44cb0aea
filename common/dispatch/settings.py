"""How a dispatcher balances and handles faults: :class:`DispatchSettings` and its two choices,
:class:`Balance` (equal or time-weighted shares) and :class:`SpeedSource` (which measured speed weighs)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from common.bounds import Bounded, bounded


class Balance(StrEnum):
    """How shares are chosen."""

    NONE = "none"
    TIME = "time"


class SpeedSource(StrEnum):
    """Which measurement of a member's speed feeds ``balance=time``.

    ``reported``: the member's own figure (a worker's patches per second of compute time; a foreman's sum
    of its workers'). ``round-trip`` (default): patches / time from the start of the round to the member's
    reply, as seen by the dispatcher; shares proportional to it converge to equal completion times (the
    fixed point of ``n_i ~ n_i / T_i`` is ``T_i = T``), transfers and co-located members included. Workers
    sharing one core overlap only partly, so the sum of their own figures overstates what their host
    delivers: on the bench's heterogeneous cluster (two equal cores) ``reported`` settled at 41/59 %,
    ``round-trip`` at 51/49 %.
    """

    REPORTED = "reported"
    ROUND_TRIP = "round-trip"


@dataclass(frozen=True)
class DispatchSettings(Bounded):
    """Balancing and fault-handling parameters of a :class:`Dispatcher`."""

    balance: Balance = Balance.TIME
    #: weight of the newest speed measurement in the moving average.
    ema_alpha: float = bounded(0.3, gt=0.0, le=1.0)
    #: the dispatcher computes a share itself (the paper's configuration) even when members exist.
    self_compute: bool = False
    #: capacity of the dispatcher itself (weight under ``balance=none``).
    self_capacity: float = bounded(1.0, gt=0.0)
    #: first suspension after a missed deadline; doubles per consecutive failure up to ``max_suspend_s``.
    suspend_s: float = bounded(1.0, gt=0.0)
    max_suspend_s: float = bounded(8.0, gt=0.0)
    #: per-request deadline = max(min_deadline_s, deadline_factor * expected time at the member's speed).
    min_deadline_s: float = bounded(0.3, gt=0.0)
    deadline_factor: float = bounded(4.0, gt=0.0)
    #: which speed measurement balances (see :class:`SpeedSource`).
    speed_source: SpeedSource = SpeedSource.ROUND_TRIP
    #: when a share cap cuts a fast member, a member with room takes its overflow only up to ``1 +
    #: overflow_slack`` times its own balanced count; the dispatcher computes the rest
    #: (:func:`~common.dispatch.plan.capped_counts`)
    overflow_slack: float = bounded(0.5, ge=0.0, le=10.0)
    #: a plan keeps the previous frame's counts while no member's new count differs from its previous one
    #: by more than this share of the frame's patches (at least one patch; 0: every change moves). A moved
    #: patch costs its previous crop on the member's link (16 kB at 128 px: 1.3 ms of 100 Mbit) and its
    #: previous spectrum at the receiver, which the measured speeds then read as the member being slower:
    #: without it, their jitter moved 3-4 patches of 192 every frame (``capataz bench dispatch``).
    move_deadband: float = bounded(0.02, ge=0.0, le=0.5)
