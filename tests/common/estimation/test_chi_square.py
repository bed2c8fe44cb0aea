"""The chi-square distribution (:mod:`common.estimation.chi_square`) against the tables and scipy."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from common.errors import InputError
from common.estimation.chi_square import chi_square_cdf, chi_square_quantile


def test_chi_square_quantiles_match_tables() -> None:
    assert chi_square_quantile(0.95, 1) == pytest.approx(3.841, abs=1e-3)
    assert chi_square_quantile(0.95, 2) == pytest.approx(5.991, abs=1e-3)
    assert chi_square_quantile(0.95, 3) == pytest.approx(7.815, abs=1e-3)
    assert chi_square_quantile(0.999, 3) == pytest.approx(16.266, abs=1e-3)
    assert chi_square_quantile(0.95, 10) == pytest.approx(18.307, abs=1e-3)
    assert chi_square_quantile(0.025, 100) == pytest.approx(74.222, abs=1e-3)
    assert chi_square_cdf(0.0, 2) == 0.0
    with pytest.raises(InputError):
        chi_square_cdf(1.0, 0)
    with pytest.raises(InputError):
        chi_square_quantile(1.0, 3)


@settings(max_examples=60, deadline=None)
@given(dof=st.integers(1, 200_000), probability=st.floats(0.001, 0.999))
def test_quantile_matches_scipy_for_any_dof(dof: int, probability: float) -> None:
    assert chi_square_quantile(probability, dof) == pytest.approx(stats.chi2.ppf(probability, dof), rel=1e-6)


@settings(max_examples=60, deadline=None)
@given(dof=st.integers(4, 5000), x=st.floats(0.01, 20_000.0))
def test_cdf_matches_scipy(dof: int, x: float) -> None:
    assert chi_square_cdf(x, dof) == pytest.approx(stats.chi2.cdf(x, dof), abs=1e-9)
