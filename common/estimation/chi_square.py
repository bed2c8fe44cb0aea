"""Chi-square gate thresholds of the filters' innovation gates (no scipy): the inverse CDF by bisection of the
closed forms for 1 to 3 degrees of freedom."""

from __future__ import annotations

import math

from common.errors import InputError


def chi_square_cdf(x: float, dof: int) -> float:
    """CDF of the chi-square distribution for 1, 2 or 3 degrees of freedom."""
    if x <= 0.0:
        return 0.0
    if dof == 1:
        return math.erf(math.sqrt(x / 2.0))
    if dof == 2:
        return 1.0 - math.exp(-x / 2.0)
    if dof == 3:
        return math.erf(math.sqrt(x / 2.0)) - math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)
    raise InputError(f"chi_square_cdf supports 1..3 degrees of freedom, got {dof}")


def chi_square_quantile(probability: float, dof: int) -> float:
    """Inverse of :func:`chi_square_cdf` (bisection, 1e-9 relative)."""
    lo, hi = 0.0, 1.0
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
