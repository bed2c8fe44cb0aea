"""The held yaw rate: estimated over a robust window of recent measured pairs, not one delta over one gap.

Without a gyro, a pair the camera stage cannot trust is bridged by holding the recent yaw rate over its
interval (``HELD``). The rate of a single pair is its delta over its stamp gap: a 20 ms gap with a small
error in its delta makes a rate of hundreds of deg/s (issue 26: one such gap held over the next 56 ms made
an 8.7 deg error). Here the rate is the weighted median of the rates of the measured pairs of the last
``window_s`` (each weighted by its gap, so a short gap counts little and one bad pair cannot move it), and
its *lag* is how long before the newest measured stamp that rate applies (the weighted mean of the pairs'
midpoints). The held pair's tolerance grows with the window's spread of rates (their noise and trend) and
the time since measured.

Pure values: the window is a tuple of :class:`MeasuredPair` carried in the tracker's frozen state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.errors import InputError

__all__ = ["DEFAULT_WINDOW_S", "HeldRate", "MeasuredPair", "held_rate", "with_measured_pair"]

#: Measured pairs kept for the held rate: those ending within this time of the newest (s).
DEFAULT_WINDOW_S = 0.3


@dataclass(frozen=True)
class MeasuredPair:
    """One measured pair: its later frame's stamp (s), its stamp gap (s) and its measured delta (rad)."""

    stop_s: float
    dt_s: float
    delta_rad: float

    @property
    def rate_rad_s(self) -> float:
        return self.delta_rad / self.dt_s

    @property
    def mid_s(self) -> float:
        return self.stop_s - 0.5 * self.dt_s


@dataclass(frozen=True)
class HeldRate:
    """The rate to hold (rad/s: the newest pair's, or the window's robust line at its midpoint), the line's
    trend (rad/s^2; 0 with fewer than :data:`MIN_TREND_PAIRS` pairs), how long before the newest stamp the
    window's pairs lie on average (s, >= 0), and the rates' weighted scatter about the line (rad/s)."""

    rate_rad_s: float
    lag_s: float
    spread_rad_s: float
    pairs: int
    trend_rad_s2: float = 0.0


#: The trend needs this many pairs.
MIN_TREND_PAIRS = 3
#: The newest pair's own rate is held unless its gap is shorter than this share of the window's median gap.
SHORT_GAP_SHARE = 0.5


def with_measured_pair(
    window: tuple[MeasuredPair, ...], pair: MeasuredPair, window_s: float = DEFAULT_WINDOW_S
) -> tuple[MeasuredPair, ...]:
    """The window with ``pair`` appended and the pairs ending more than ``window_s`` before it dropped (the
    newest pair is always kept, however long its gap)."""
    if not (math.isfinite(pair.stop_s) and math.isfinite(pair.delta_rad)) or not pair.dt_s > 0.0:
        raise InputError(f"a measured pair needs finite values and a positive gap, got {pair}")
    if window and pair.stop_s <= window[-1].stop_s:
        raise InputError(
            f"measured pairs must come in stamp order, got {window[-1].stop_s} then {pair.stop_s}"
        )
    kept = tuple(p for p in window if p.stop_s >= pair.stop_s - window_s)
    return (*kept, pair)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value where the cumulative weight (sorted by value) first reaches half the total; ties between
    two halves are averaged, so a symmetric pair gives its midpoint."""
    order = np.argsort(values, kind="stable")
    v, w = values[order], weights[order]
    cumulative = np.cumsum(w)
    half = 0.5 * cumulative[-1]
    i = int(np.searchsorted(cumulative, half - 1e-12 * cumulative[-1]))
    if abs(cumulative[i] - half) <= 1e-12 * cumulative[-1] and i + 1 < v.size:
        return float(0.5 * (v[i] + v[i + 1]))
    return float(v[i])


def held_rate(window: tuple[MeasuredPair, ...]) -> HeldRate | None:
    """The robust rate of the window's pairs at its newest stamp (None for an empty window): a weighted
    Theil-Sen line through the pairs' rates at their midpoints (the slope is the weighted median of the
    slopes between pairs, each weighted by the product of their gaps; the rate at the newest stamp the
    weighted median of the pairs' rates carried along it to the newest pair's midpoint), so an accelerating
    swing is not held at the rate it had a few pairs ago, and a pair far off the others (a short gap's bad
    delta) moves nothing."""
    if not window:
        return None
    rates = np.array([p.rate_rad_s for p in window])
    weights = np.array([p.dt_s for p in window])
    mids = np.array([p.mid_s for p in window])
    newest = window[-1].stop_s
    trend = 0.0
    if rates.size >= MIN_TREND_PAIRS:
        i, j = np.triu_indices(rates.size, k=1)
        apart = mids[j] - mids[i]
        usable = apart > 1e-6
        if np.any(usable):
            slopes = (rates[j] - rates[i])[usable] / apart[usable]
            trend = _weighted_median(slopes, (weights[i] * weights[j])[usable])
    # the line at the newest pair's midpoint: no further than the old one-pair rate from its data
    at_s = window[-1].mid_s
    carried = rates + trend * (at_s - mids)
    rate = _weighted_median(carried, weights)
    residual = np.abs(carried - rate)
    spread = float(np.sum(weights * residual) / np.sum(weights))
    # the newest pair's own rate is the freshest, unless its gap is short: then its delta's error makes a
    # rate error of that error over a few ms (issue 26: 155 deg/s from a 20 ms gap), and the line's is held
    last = window[-1]
    if last.dt_s >= SHORT_GAP_SHARE * float(np.median(weights)):
        rate = last.rate_rad_s
    lag = newest - float(np.sum(weights * mids) / np.sum(weights))
    return HeldRate(rate, max(lag, 0.0), spread, len(window), trend)
