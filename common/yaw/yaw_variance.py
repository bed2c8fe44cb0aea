"""The yaw's variance: the sum of its pairs' errors, measured pairs correlated in time.

The yaw is the sum of its pairs' deltas, but not its variance the sum of theirs: consecutive measured pairs
err alike (the motion that biases one pair's fit lasts into the next), so :func:`add_pair_variance` adds each
measured pair's covariance with the measured pairs before it, a first-order Gauss-Markov error in time
(:func:`pair_covariance_rad2` is the same model as a run's whole covariance, for fitting and tests). Bridged
and held pairs (:mod:`common.yaw.honest`) add their own variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError

__all__ = [
    "CORRELATED_SHARE",
    "CORRELATION_TIME_S",
    "PairErrorModel",
    "add_pair_variance",
    "pair_covariance_rad2",
]

#: Measured pairs' errors are correlated in time: a share ``CORRELATED_SHARE`` of each measured pair's
#: variance is a first-order Gauss-Markov error with time constant ``CORRELATION_TIME_S`` (two measured pairs
#: ``t`` apart correlate by ``CORRELATED_SHARE * exp(-t / CORRELATION_TIME_S)``); the rest is white. A pair's
#: own variance is unchanged; the yaw's variance adds the cross terms (:func:`add_pair_variance`). Fitted by
#: Gaussian maximum likelihood of each run's whole error vector on the field suite's seeds 0-9 (100 frames per
#: scenario, with and without the gyro; ``bench consistency --fit-yaw-correlation --seeds 20 --field-frames
#: 100``): the published yaw's mean NEES there is 0.81 with 0.978 of its errors within 2 sigma, against 4.64
#: and 0.623 when the pairs were summed as if independent. At 40 fps the correlation of pairs 50 ms apart is
#: what it is for neighbours at 20 fps (a probe): it lives in time, not in frames.
CORRELATED_SHARE = 0.705
CORRELATION_TIME_S = 0.2686


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


def add_pair_variance(
    yaw_variance_rad2: float,
    memory_rad: float,
    variance_rad2: float,
    step_s: float,
    measured: bool,
    model: PairErrorModel | None = None,
) -> tuple[float, float]:
    """The yaw's variance after one more pair of ``variance_rad2`` (a ``step_s`` after the last), and the
    measured pairs' correlated memory after it: ``(yaw_variance_rad2, memory_rad)``.

    With ``q`` = :data:`CORRELATED_SHARE`, ``phi = exp(-step_s / CORRELATION_TIME_S)`` and ``G`` the memory
    (the measured pairs' correlated errors' standard deviations, each decayed by ``exp(-age / time)``), a
    measured pair adds its variance and twice its covariance with all measured pairs before it::

        var += v + 2 sqrt(q v) phi G;   G = phi G + sqrt(q v)

    A bridged or held pair (its error comes from the gyro or the held rate, independent of the camera's)
    adds its variance; the memory decays over it. This is exactly ``1^T C 1`` for the pairs' covariance
    ``C`` (:func:`pair_covariance_rad2`).
    """
    if not (variance_rad2 >= 0.0 and math.isfinite(variance_rad2) and step_s >= 0.0 and memory_rad >= 0.0):
        raise InputError(
            f"need variance >= 0, step >= 0, memory >= 0, got {variance_rad2}, {step_s}, {memory_rad}"
        )
    errors = model or PairErrorModel()
    decay = math.exp(-step_s / errors.correlation_time_s)
    if not measured:
        return yaw_variance_rad2 + variance_rad2, decay * memory_rad
    correlated = math.sqrt(errors.correlated_share * variance_rad2)
    cross = correlated * decay * memory_rad
    return yaw_variance_rad2 + variance_rad2 + 2.0 * cross, decay * memory_rad + correlated


def pair_covariance_rad2(
    variances_rad2: npt.ArrayLike,
    stop_s: npt.ArrayLike,
    measured: npt.ArrayLike,
    model: PairErrorModel | None = None,
) -> npt.NDArray[np.float64]:
    """The covariance (N, N) of a run's N pair errors: each pair's variance on the diagonal, and
    ``share * sqrt(v_i v_j) * exp(-|t_i - t_j| / time)`` between two measured pairs (ending at ``stop_s``).
    The sum of its leading ``k x k`` block is the yaw's variance after ``k`` pairs
    (:func:`add_pair_variance`)."""
    v = np.asarray(variances_rad2, dtype=np.float64)
    t = np.asarray(stop_s, dtype=np.float64)
    m = np.asarray(measured, dtype=bool)
    errors = model or PairErrorModel()
    if v.ndim != 1 or t.shape != v.shape or m.shape != v.shape:
        shapes = f"{v.shape}, {t.shape}, {m.shape}"
        raise InputError(f"need variances, stops and measured flags of one shape (N,), got {shapes}")
    if not (np.all(np.isfinite(v)) and np.all(v >= 0.0) and np.all(np.isfinite(t))):
        raise InputError("need finite variances >= 0 and finite stamps")
    correlated = np.sqrt(errors.correlated_share * v) * m
    apart = np.abs(t[:, None] - t[None, :])
    out = np.outer(correlated, correlated) * np.exp(-apart / errors.correlation_time_s)
    np.fill_diagonal(out, v)
    return out
