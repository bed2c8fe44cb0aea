"""Chi-square distribution without scipy: the CDF in closed form for 1 to 3 degrees of freedom (the filters'
innovation gates) and through the regularised incomplete gamma function for any other (the consistency
bounds of a mean NEES over many samples, :mod:`common.consistency`); the inverse CDF by bisection."""

from __future__ import annotations

import math

from common.errors import InputError

#: Iterations of the incomplete gamma's series / continued fraction (enough for a = 1e7 at 1e-14).
_MAX_TERMS = 200_000
_EPS = 1e-15
_TINY = 1e-300


def _lower_regularised_gamma(a: float, x: float) -> float:
    """P(a, x) = gamma(a, x) / Gamma(a): the series below ``a + 1``, the continued fraction above (Lentz)."""
    log_prefix = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1.0:
        term = total = 1.0 / a
        ap = a
        for _ in range(_MAX_TERMS):
            ap += 1.0
            term *= x / ap
            total += term
            if abs(term) < abs(total) * _EPS:
                break
        return min(1.0, total * math.exp(log_prefix))
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        step = d * c
        h *= step
        if abs(step - 1.0) < _EPS:
            break
    return max(0.0, 1.0 - math.exp(log_prefix) * h)


def chi_square_cdf(x: float, dof: int) -> float:
    """CDF of the chi-square distribution with ``dof`` >= 1 degrees of freedom."""
    if dof < 1 or int(dof) != dof:
        raise InputError(f"chi_square_cdf needs a whole number of degrees of freedom >= 1, got {dof}")
    if x <= 0.0:
        return 0.0
    if dof == 1:
        return math.erf(math.sqrt(x / 2.0))
    if dof == 2:
        return 1.0 - math.exp(-x / 2.0)
    if dof == 3:
        return math.erf(math.sqrt(x / 2.0)) - math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)
    return _lower_regularised_gamma(dof / 2.0, x / 2.0)


def chi_square_quantile(probability: float, dof: int) -> float:
    """Inverse of :func:`chi_square_cdf` (bisection, 1e-9 relative)."""
    if not 0.0 < probability < 1.0:
        raise InputError(f"probability must lie in (0, 1), got {probability}")
    # (the gates' bracket of 1 kept for 1..3 dof: their thresholds stay bit for bit what they were)
    lo, hi = 0.0, 1.0 if dof <= 3 else float(dof)
    while chi_square_cdf(hi, dof) < probability:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi_square_cdf(mid, dof) < probability:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9 * hi:
            break
    return 0.5 * (lo + hi)
