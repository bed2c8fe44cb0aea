"""The chi-square gate thresholds (:mod:`common.estimation.chi_square`) against the tables."""

from __future__ import annotations

import pytest

from common.errors import InputError
from common.estimation.chi_square import chi_square_cdf, chi_square_quantile


def test_chi_square_quantiles_match_tables() -> None:
    assert chi_square_quantile(0.95, 1) == pytest.approx(3.841, abs=1e-3)
    assert chi_square_quantile(0.95, 2) == pytest.approx(5.991, abs=1e-3)
    assert chi_square_quantile(0.95, 3) == pytest.approx(7.815, abs=1e-3)
    assert chi_square_quantile(0.999, 3) == pytest.approx(16.266, abs=1e-3)
    assert chi_square_cdf(0.0, 2) == 0.0
    with pytest.raises(InputError):
        chi_square_cdf(1.0, 4)
