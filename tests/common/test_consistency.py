"""Consistency statistics (:mod:`common.consistency`): shares within k sigma and the mean NEES against its
chi-square bounds, on Gaussian samples with known covariances."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.consistency import (
    NORMAL_SHARES,
    consistency,
    error_consistency,
    nees_bounds,
    normalised_errors_squared,
)
from common.errors import InputError


def _gaussian(seed: int, n: int, dof: int, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` errors of ``dof`` components drawn from random covariances; the claimed covariances are the
    true ones times ``scale**2``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, dof, dof)) * rng.uniform(0.01, 10.0, size=(n, 1, 1))
    P = A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(dof)
    L = np.linalg.cholesky(P)
    e = (L @ rng.normal(size=(n, dof, 1)))[:, :, 0]
    return e, P * scale**2


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), dof=st.integers(1, 6))
def test_honest_gaussian_errors_are_consistent(seed: int, dof: int) -> None:
    e, P = _gaussian(seed, 4000, dof)
    c = error_consistency(e if dof > 1 else e[:, 0], P if dof > 1 else P[:, 0, 0])
    assert c.samples == 4000 and c.dof == dof
    # 4000 samples: the share's standard error is at most 0.008
    for share, expected in zip(
        (c.within_1_sigma, c.within_2_sigma, c.within_3_sigma), NORMAL_SHARES, strict=True
    ):
        assert share == pytest.approx(expected, abs=0.035)
    assert c.within_2_sigma == pytest.approx(0.954, abs=0.02)
    assert c.nees_mean == pytest.approx(dof, rel=0.1)
    assert c.nees_lower < dof < c.nees_upper


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), dof=st.integers(1, 4), scale=st.floats(0.2, 5.0))
def test_scaled_covariances_move_the_statistics_the_right_way(seed: int, dof: int, scale: float) -> None:
    """An overconfident covariance (scale < 1) raises the NEES by 1/scale^2 and lowers every share; an
    over-cautious one the opposite."""
    e, P = _gaussian(seed, 500, dof)
    honest = error_consistency(e, P)
    claimed = error_consistency(e, P * scale**2)
    assert claimed.nees_mean == pytest.approx(honest.nees_mean / scale**2, rel=1e-6)
    pairs = [(claimed.within_2_sigma, honest.within_2_sigma), (claimed.within_1_sigma, honest.within_1_sigma)]
    for after, before in pairs:
        assert after <= before if scale < 1.0 else after >= before


def test_far_off_covariances_fail_the_bounds() -> None:
    e, P = _gaussian(7, 2000, 3)
    assert error_consistency(e, P).nees_within_bounds
    assert not error_consistency(e, P * 0.25).nees_within_bounds  # 2x overconfident
    assert not error_consistency(e, P * 4.0).nees_within_bounds  # 2x too cautious
    assert error_consistency(e, P * 0.25).within_2_sigma < 0.75


@settings(max_examples=30, deadline=None)
@given(samples=st.integers(1, 20_000), dof=st.integers(1, 6))
def test_bounds_bracket_the_mean_and_narrow_with_samples(samples: int, dof: int) -> None:
    lower, upper = nees_bounds(samples, dof)
    assert 0.0 < lower < dof < upper
    lower2, upper2 = nees_bounds(samples * 4, dof)
    assert lower < lower2 and upper2 < upper
    # the normal approximation of the mean: dof +- 1.96 sqrt(2 dof / N)
    if samples * dof > 2000:
        half = 1.96 * math.sqrt(2.0 * dof / samples)
        assert lower == pytest.approx(dof - half, abs=0.1 * half)
        assert upper == pytest.approx(dof + half, abs=0.1 * half)


def test_degenerate_covariances_and_bad_input() -> None:
    nees = normalised_errors_squared([[1.0, 0.0], [0.0, 0.0], [1.0, 1.0]], np.zeros((3, 2, 2)))
    assert np.isinf(nees[0]) and nees[1] == 0.0 and np.isinf(nees[2])
    assert normalised_errors_squared([2.0], [4.0])[0] == pytest.approx(1.0)
    assert consistency([], 2).samples == 0 and math.isnan(consistency([], 2).nees_mean)
    with pytest.raises(InputError):
        normalised_errors_squared([[1.0, 2.0]], np.eye(3)[None])
    with pytest.raises(InputError):
        normalised_errors_squared([np.nan], [1.0])
    with pytest.raises(InputError):
        consistency([-1.0], 1)
    with pytest.raises(InputError):
        nees_bounds(0, 1)
