"""The yaw's variance: the sum of its pairs' errors, measured pairs correlated in time, held ones in a hold.

The yaw is the sum of its pairs' deltas, but not its variance the sum of theirs: consecutive measured pairs
err alike (the motion that biases one pair's fit lasts into the next), so :func:`add_pair_variance` adds each
measured pair's covariance with the measured pairs before it, a first-order Gauss-Markov error in time
(:func:`pair_covariance_rad2` is the same model as a run's whole covariance, for fitting and tests). The
pairs of one hold (:mod:`common.yaw.honest`) go together too; a bridged pair adds its own variance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.provenance import Provenance

__all__ = [
    "CORRELATED_SHARE",
    "CORRELATION_TIME_S",
    "PairErrorModel",
    "YawVariance",
    "add_pair_variance",
    "pair_covariance_rad2",
]

#: Measured pairs' errors are correlated in time: a share ``CORRELATED_SHARE`` of each measured pair's
#: variance is a first-order Gauss-Markov error with time constant ``CORRELATION_TIME_S`` (two measured pairs
#: ``t`` apart correlate by ``CORRELATED_SHARE * exp(-t / CORRELATION_TIME_S)``); the rest is white. A pair's
#: own variance is unchanged; the yaw's variance adds the cross terms (:func:`add_pair_variance`). Fitted by
#: Gaussian maximum likelihood of each run's whole error vector on the field suite's seeds 0-9 (the suite's
#: 600-frame flights, with and without the gyro; ``bench consistency --fit-yaw-correlation --seeds 20``):
#: the published yaw's mean NEES there is 0.88 with 0.965 of its errors within 2 sigma, against 4.65 and
#: 0.648 when the pairs were summed as if independent (fit on seeds 0-4 and scored on 5-9: 0.63, 0.976; the
#: other way 1.11, 0.957). It was 0.705 and 0.269 s, fitted on 100-frame flights with the pair variances
#: before theirs were fitted on the whole flights: 0.66 and 0.988, cautious. At 40 fps the correlation of
#: pairs 50 ms apart is what it is for neighbours at 20 fps (a probe): it lives in time, not in frames.
#: Held out (seeds 10-19) with the pairs' per-patch variances: mean NEES 0.78, 0.969 within 2 sigma; refitted
#: on those variances the pair moves to 0.694 and 0.219 s, no more likely (0.006 nats a pair) and more
#: cautious: kept.
CORRELATED_SHARE = 0.627
CORRELATION_TIME_S = 0.2156


@dataclass(frozen=True)
class PairErrorModel:
    """How the measured pairs' errors go together (defaults: the fitted constants): the share of their
    variance that is a Gauss-Markov error, and its time constant (s)."""

    correlated_share: float = CORRELATED_SHARE
    correlation_time_s: float = CORRELATION_TIME_S

    def __post_init__(self) -> None:
        time_s = self.correlation_time_s
        if not (0.0 <= self.correlated_share <= 1.0 and time_s > 0.0 and math.isfinite(time_s)):
            raise InputError(f"need a share in [0, 1] and a finite time > 0, got {self}")


@dataclass(frozen=True)
class YawVariance:
    """The yaw's variance, and what the next pair's covariance with the pairs before it needs: the measured
    pairs' correlated memory (their correlated errors' std, each decayed by ``exp(-age / time)``, rad) and
    the current hold's (its held pairs' std summed, rad; 0 after any pair not held)."""

    variance_rad2: float = 0.0
    measured_memory_rad: float = 0.0
    held_memory_rad: float = 0.0

    def __post_init__(self) -> None:
        values = (self.variance_rad2, self.measured_memory_rad, self.held_memory_rad)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise InputError(f"need a finite variance and memories >= 0, got {self}")


def add_pair_variance(
    before: YawVariance,
    variance_rad2: float,
    step_s: float,
    provenance: Provenance,
    model: PairErrorModel | None = None,
) -> YawVariance:
    """The yaw's variance after one more pair of ``variance_rad2``, a ``step_s`` after the last.

    With ``q`` = :data:`CORRELATED_SHARE`, ``phi = exp(-step_s / CORRELATION_TIME_S)`` and ``G`` the measured
    pairs' memory, a measured pair adds its variance and twice its covariance with the measured pairs before
    it::

        var += v + 2 sqrt(q v) phi G;   G = phi G + sqrt(q v)

    The pairs of one hold share the rate they hold (and what it missed since), so their errors go together:
    a held pair adds ``v + 2 sqrt(v) H`` with ``H`` the hold's memory, as if fully correlated (an upper
    bound). A bridged pair (the gyro's error) adds its variance. The memories decay or end accordingly. This
    is exactly ``1^T C 1`` for the pairs' covariance ``C`` (:func:`pair_covariance_rad2`).
    """
    if not (variance_rad2 >= 0.0 and math.isfinite(variance_rad2) and step_s >= 0.0):
        raise InputError(f"need a finite variance >= 0 and a step >= 0, got {variance_rad2}, {step_s}")
    errors = model or PairErrorModel()
    decay = math.exp(-step_s / errors.correlation_time_s)
    measured_memory = decay * before.measured_memory_rad
    if provenance is Provenance.MEASURED:
        correlated = math.sqrt(errors.correlated_share * variance_rad2)
        cross = correlated * measured_memory
        return YawVariance(before.variance_rad2 + variance_rad2 + 2.0 * cross, measured_memory + correlated)
    if provenance is Provenance.HELD:
        std = math.sqrt(variance_rad2)
        cross = std * before.held_memory_rad
        return YawVariance(
            before.variance_rad2 + variance_rad2 + 2.0 * cross, measured_memory, before.held_memory_rad + std
        )
    return YawVariance(before.variance_rad2 + variance_rad2, measured_memory)


def pair_covariance_rad2(
    variances_rad2: npt.ArrayLike,
    stop_s: npt.ArrayLike,
    provenance: Sequence[Provenance],
    model: PairErrorModel | None = None,
) -> npt.NDArray[np.float64]:
    """The covariance (N, N) of a run's N pair errors (in order): each pair's variance on the diagonal,
    ``share * sqrt(v_i v_j) * exp(-|t_i - t_j| / time)`` between two measured pairs (ending at ``stop_s``),
    ``sqrt(v_i v_j)`` between two pairs of one hold (consecutive held pairs). The sum of its leading ``k x k``
    block is the yaw's variance after ``k`` pairs (:func:`add_pair_variance`)."""
    v = np.asarray(variances_rad2, dtype=np.float64)
    t = np.asarray(stop_s, dtype=np.float64)
    m = np.array([p is Provenance.MEASURED for p in provenance], dtype=bool)
    held = np.array([p is Provenance.HELD for p in provenance], dtype=bool)
    errors = model or PairErrorModel()
    if v.ndim != 1 or t.shape != v.shape or m.shape != v.shape:
        shapes = f"{v.shape}, {t.shape}, {m.shape}"
        raise InputError(f"need variances, stops and provenances of one length (N,), got {shapes}")
    if not (np.all(np.isfinite(v)) and np.all(v >= 0.0) and np.all(np.isfinite(t))):
        raise InputError("need finite variances >= 0 and finite stamps")
    correlated = np.sqrt(errors.correlated_share * v) * m
    apart = np.abs(t[:, None] - t[None, :])
    out = np.outer(correlated, correlated) * np.exp(-apart / errors.correlation_time_s)
    hold = np.cumsum(~held)  # the pairs of one hold share this number
    same_hold = held[:, None] & held[None, :] & (hold[:, None] == hold[None, :])
    out += np.where(same_hold, np.sqrt(np.outer(v, v)), 0.0)
    np.fill_diagonal(out, v)
    return out
