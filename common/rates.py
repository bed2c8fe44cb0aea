"""Rates of a stream and of counters: what ``capataz hz`` and ``capataz status`` print.

:func:`interval_stats` is ``ros2 topic hz``'s figure: over the arrival times of the last messages, the mean
rate (one over the mean interval) and the minimum, maximum and standard deviation of the intervals.
:func:`counter_rates` turns two snapshots of a member's cumulative counters into per-second rates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from common.errors import InputError


@dataclass(frozen=True)
class IntervalStats:
    """The intervals between consecutive arrivals of one stream (seconds, one receiver's clock)."""

    #: messages the figures are made from (intervals + 1)
    messages: int
    #: messages per second: 1 / mean interval (inf when every arrival has the same time)
    rate_hz: float
    mean_s: float
    min_s: float
    max_s: float
    #: population standard deviation of the intervals (ros2 topic hz's "std dev")
    std_s: float


def interval_stats(arrivals_s: Sequence[float]) -> IntervalStats | None:
    """Figures of the intervals between ``arrivals_s`` (non-decreasing); None for fewer than 2 arrivals."""
    times = np.asarray(arrivals_s, dtype=float)
    if times.ndim != 1:
        raise InputError(f"arrival times must be a sequence, got shape {times.shape}")
    if times.size < 2:
        return None
    if not np.all(np.isfinite(times)):
        raise InputError("arrival times must be finite")
    intervals = np.diff(times)
    if np.any(intervals < 0):
        raise InputError("arrival times must not decrease")
    mean = float(intervals.mean())
    return IntervalStats(
        messages=int(times.size),
        rate_hz=1.0 / mean if mean > 0 else math.inf,
        mean_s=mean,
        min_s=float(intervals.min()),
        max_s=float(intervals.max()),
        std_s=float(intervals.std()),
    )


def counter_rates(earlier: Mapping[str, int], later: Mapping[str, int], elapsed_s: float) -> dict[str, float]:
    """Per-second rate of each counter between two snapshots ``elapsed_s`` apart (the member's clock).

    A counter absent from ``earlier`` started at 0; one that went down (the member restarted) has no rate
    and is left out.
    """
    if not (math.isfinite(elapsed_s) and elapsed_s > 0):
        raise InputError(f"elapsed time must be positive, got {elapsed_s!r}")
    rates: dict[str, float] = {}
    for name, value in later.items():
        delta = value - earlier.get(name, 0)
        if delta >= 0:
            rates[name] = delta / elapsed_s
    return rates
