"""Whether a published uncertainty is honest: errors against truth normalised by their own covariance.

For ``N`` errors ``e_i`` (each of ``d`` components) with covariances ``P_i`` the normalised estimation error
squared is ``NEES_i = e_i^T P_i^-1 e_i``; an honest (consistent) estimator's NEES follow a chi-square law of
``d`` degrees of freedom, so

- the share of errors "within k sigma", ``NEES_i <= q_d(p_k)`` with ``p_k = P(|z| <= k)`` of a standard normal
  (0.683, 0.954, 0.997), is about ``p_k`` for any ``d`` (for ``d = 1`` it is ``|e| <= k sigma`` exactly);
- the mean NEES is about ``d``, and ``N`` times it is chi-square of ``N d`` degrees of freedom if the errors
  are independent: its two-sided 95 % bounds are ``q_{Nd}(0.025) / N`` and ``q_{Nd}(0.975) / N``.

Errors of a time series are correlated (an accumulated yaw, a filter's attitude): the mean NEES still says
whether the covariance is too small (above ``d``) or too large (below), but the bounds then are narrower than
its true spread. Shares below the normal's say the covariance is overconfident, above it too cautious.
:func:`seed_bounds` gives the spread such a mean really has over independent runs (seeds): the bootstrap
over whole runs (a block bootstrap with a run as the block; Efron and Tibshirani, *An Introduction to the
Bootstrap*, 1993), which keeps each run's correlation.

:func:`ensemble_consistency` is the chi-square test these bounds come from, as it is meant for correlated
series (Bar-Shalom, Li and Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001,
sec. 5.4.2): at each time step ``k`` the average NEES over ``N`` independent runs (seeds),
``ANEES_k = (1/N) sum_i NEES_ik``, is ``1/N`` times chi-square of ``N d`` degrees of freedom for an honest
estimator, so about 95 % of the steps fall within their two-sided 95 % bounds (:func:`nees_bounds` of ``N``
samples); steps above them say overconfident, below them cautious. Runs are independent; a run's steps
need not be.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.estimation.chi_square import chi_square_quantile
from common.types import FloatArray

#: ``P(|z| <= k)`` of a standard normal for k = 1, 2, 3.
NORMAL_SHARES = tuple(math.erf(k / math.sqrt(2.0)) for k in (1, 2, 3))
#: Two-sided probability of the mean NEES bounds.
NEES_BOUND_PROBABILITY = 0.95
#: Resamples of :func:`seed_bounds`.
SEED_RESAMPLES = 2000


@dataclass(frozen=True)
class Consistency:
    """Shares of errors within 1, 2, 3 sigma, the mean NEES and its chi-square bounds (``samples`` errors of
    ``dof`` components); NaN without samples."""

    samples: int
    dof: int
    within_1_sigma: float
    within_2_sigma: float
    within_3_sigma: float
    nees_mean: float
    nees_lower: float
    nees_upper: float

    @property
    def nees_within_bounds(self) -> bool:
        return bool(self.nees_lower <= self.nees_mean <= self.nees_upper)

    def as_dict(self) -> dict[str, float | int | bool]:
        return {
            "samples": self.samples,
            "dof": self.dof,
            "within_1_sigma": self.within_1_sigma,
            "within_2_sigma": self.within_2_sigma,
            "within_3_sigma": self.within_3_sigma,
            "nees_mean": self.nees_mean,
            "nees_lower": self.nees_lower,
            "nees_upper": self.nees_upper,
            "nees_within_bounds": self.nees_within_bounds,
        }


def normalised_errors_squared(errors: npt.ArrayLike, covariances: npt.ArrayLike) -> FloatArray:
    """NEES per sample: ``errors`` (N,) with variances (N,), or (N, d) with covariances (N, d, d).

    A sample whose covariance is not positive definite (or not finite) gives ``inf`` (an error the
    estimator claimed impossible) unless its error is zero too.
    """
    e = np.asarray(errors, dtype=np.float64)
    P = np.asarray(covariances, dtype=np.float64)
    if e.ndim == 1:
        e, P = e[:, None], P.reshape(-1, 1, 1)
    if e.ndim != 2 or P.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise InputError(f"need errors (N, d) and covariances (N, d, d), got {e.shape} and {P.shape}")
    if not np.all(np.isfinite(e)):
        raise InputError("errors must be finite")
    out = np.full(e.shape[0], np.inf)
    good = np.all(np.isfinite(P), axis=(1, 2))
    if np.any(good):
        eigen = np.linalg.eigvalsh(0.5 * (P[good] + np.swapaxes(P[good], 1, 2)))
        definite = np.zeros(e.shape[0], dtype=bool)
        definite[np.flatnonzero(good)] = eigen[:, 0] > 0.0
        if np.any(definite):
            solved = np.linalg.solve(P[definite], e[definite][:, :, None])[:, :, 0]
            out[definite] = np.sum(e[definite] * solved, axis=1)
    out[~np.isfinite(out) & np.all(e == 0.0, axis=1)] = 0.0
    return out


def nees_bounds(samples: int, dof: int, probability: float = NEES_BOUND_PROBABILITY) -> tuple[float, float]:
    """Two-sided ``probability`` bounds of the mean of ``samples`` independent chi-square(``dof``) values."""
    if samples < 1 or dof < 1:
        raise InputError(f"need samples >= 1 and dof >= 1, got {samples} and {dof}")
    tail = (1.0 - probability) / 2.0
    total = samples * dof
    return chi_square_quantile(tail, total) / samples, chi_square_quantile(1.0 - tail, total) / samples


def check_nees(values: FloatArray) -> None:
    """Raise :class:`~common.errors.InputError` unless every NEES of ``values`` is >= 0 (inf allowed)."""
    if np.any(np.isnan(values)) or np.any(values < 0.0):
        raise InputError("NEES values must be >= 0 (inf allowed)")


def consistency(nees: npt.ArrayLike, dof: int) -> Consistency:
    """Shares within 1, 2, 3 sigma and the mean NEES with its bounds, of NEES values of ``dof`` components."""
    values = np.asarray(nees, dtype=np.float64).ravel()
    if dof < 1:
        raise InputError(f"dof must be >= 1, got {dof}")
    check_nees(values)
    if values.size == 0:
        nan = math.nan
        return Consistency(0, dof, nan, nan, nan, nan, nan, nan)
    one, two, three = (float(np.mean(values <= chi_square_quantile(p, dof))) for p in NORMAL_SHARES)
    lower, upper = nees_bounds(int(values.size), dof)
    return Consistency(int(values.size), dof, one, two, three, float(np.mean(values)), lower, upper)


def error_consistency(errors: npt.ArrayLike, covariances: npt.ArrayLike) -> Consistency:
    """:func:`consistency` of errors with their covariances (:func:`normalised_errors_squared`)."""
    e = np.asarray(errors, dtype=np.float64)
    dof = 1 if e.ndim == 1 else int(e.shape[1])
    return consistency(normalised_errors_squared(e, covariances), dof)


@dataclass(frozen=True)
class EnsembleConsistency:
    """The per-step chi-square test over independent runs (:func:`ensemble_consistency`): how many steps had
    at least ``min_runs`` runs, the median runs per step, and the shares of those steps whose average NEES
    is within its two-sided bounds, above them (overconfident) and below them (cautious); NaN without
    steps."""

    steps: int
    runs_median: float
    within: float
    above: float
    below: float

    def as_dict(self) -> dict[str, float | int]:
        return {
            "steps": self.steps,
            "runs_median": self.runs_median,
            "within": self.within,
            "above": self.above,
            "below": self.below,
        }


def ensemble_consistency(
    steps: Sequence[npt.ArrayLike],
    dof: int,
    min_runs: int = 2,
    probability: float = NEES_BOUND_PROBABILITY,
) -> EnsembleConsistency:
    """Bar-Shalom's Monte Carlo NEES test (the module docstring): ``steps`` holds, for each time step, the
    NEES of the independent runs that have a sample there (one per run; a step with fewer than ``min_runs``
    is left out); each step's average NEES is compared with :func:`nees_bounds` of that many samples."""
    if dof < 1 or min_runs < 1:
        raise InputError(f"need dof >= 1 and min_runs >= 1, got {dof} and {min_runs}")
    kept = [v for v in (np.asarray(s, dtype=np.float64).ravel() for s in steps) if v.size >= min_runs]
    for values in kept:
        check_nees(values)
    if not kept:
        nan = math.nan
        return EnsembleConsistency(0, nan, nan, nan, nan)
    above = below = 0
    bounds: dict[int, tuple[float, float]] = {}
    for values in kept:
        if values.size not in bounds:
            bounds[values.size] = nees_bounds(int(values.size), dof, probability)
        lower, upper = bounds[values.size]
        mean = float(np.mean(values))
        above += mean > upper
        below += mean < lower
    n = len(kept)
    runs = float(np.median([v.size for v in kept]))
    return EnsembleConsistency(n, runs, (n - above - below) / n, above / n, below / n)


def seed_bounds(
    runs: Sequence[npt.ArrayLike],
    probability: float = NEES_BOUND_PROBABILITY,
    resamples: int = SEED_RESAMPLES,
    rng_seed: int = 0,
) -> tuple[float, float]:
    """Two-sided ``probability`` bounds of the pooled mean NEES of independent ``runs`` (each run's NEES
    values, correlated within the run): the percentiles of the pooled mean over ``resamples`` draws of as
    many runs with replacement (``rng_seed``: the same runs give the same bounds). NaN with fewer than 2
    runs that have samples; always within the runs' smallest and largest mean."""
    values = [np.asarray(r, dtype=np.float64).ravel() for r in runs]
    values = [v for v in values if v.size]
    if not 0.0 < probability < 1.0 or resamples < 1:
        raise InputError(f"need 0 < probability < 1 and resamples >= 1, got {probability} and {resamples}")
    if len(values) < 2:
        return math.nan, math.nan
    sums = np.array([float(np.sum(v)) for v in values])
    counts = np.array([v.size for v in values], dtype=np.float64)
    rng = np.random.default_rng(rng_seed)
    drawn = rng.integers(0, len(values), size=(resamples, len(values)))
    means = np.sum(sums[drawn], axis=1) / np.sum(counts[drawn], axis=1)
    tail = (1.0 - probability) / 2.0
    lower, upper = np.quantile(means, [tail, 1.0 - tail])
    return float(lower), float(upper)


def fit_variance_terms(
    errors: npt.ArrayLike, terms: npt.ArrayLike, offset: npt.ArrayLike | None = None
) -> FloatArray:
    """Coefficients ``c >= 0`` of a variance model ``var_i = offset_i + sum_k c_k terms_ik`` by Gaussian
    maximum likelihood on scalar ``errors`` (N,) with their ``terms`` (N, K) and a known part ``offset``
    (N,; None: 0): the minimum of ``sum_i log var_i + e_i^2 / var_i`` over ``log c`` (Nelder-Mead). A model
    with one term and no offset gives ``mean(e^2 / term)``: a mean NEES of 1 on the fitted samples."""
    e = np.asarray(errors, dtype=np.float64)
    f = np.asarray(terms, dtype=np.float64)
    known = np.zeros(e.shape) if offset is None else np.asarray(offset, dtype=np.float64)
    if e.ndim != 1 or f.ndim != 2 or f.shape[0] != e.size or e.size == 0 or f.shape[1] == 0:
        raise InputError(f"need errors (N,) and terms (N, K), got {e.shape} and {f.shape}")
    if known.shape != e.shape:
        raise InputError(f"need an offset (N,) = {e.shape}, got {known.shape}")
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(f)) and np.all(f >= 0.0)):
        raise InputError("errors must be finite and terms finite and >= 0")
    if not (np.all(np.isfinite(known)) and np.all(known >= 0.0)):
        raise InputError("the offset must be finite and >= 0")
    if np.any(known + f.sum(axis=1) <= 0.0) or np.any(f.sum(axis=0) <= 0.0):
        raise InputError("every sample needs a positive term or offset and every term a positive sample")
    from scipy.optimize import minimize  # the one core function that needs it: imported where used

    e2 = e**2

    def nll(log_c: FloatArray) -> float:
        var = known + f @ np.exp(log_c)
        return float(np.sum(np.log(var) + e2 / var))

    # start from each term alone fitted to the whole error (a mean NEES of 1 per term), shared among terms
    alone = np.array([np.mean(e2[f[:, k] > 0] / f[f[:, k] > 0, k]) for k in range(f.shape[1])])
    start = np.log(np.maximum(alone, 1e-300))  # errors all 0: start tiny, not at log 0
    start -= math.log(f.shape[1])
    best = minimize(nll, start, method="Nelder-Mead", options={"maxiter": 4000, "xatol": 1e-7, "fatol": 1e-9})
    return np.asarray(np.exp(best.x), dtype=np.float64)
