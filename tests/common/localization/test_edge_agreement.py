"""How much the points of each model edge agree in their offsets (:func:`common.localization.refine.
edge_agreement`) and the published covariance it scales (issue 26's localizer line): from a truth generator,
offsets that scatter along each edge give a small ratio and an offset each edge's points share a large one;
the ratio does not depend on how points or edges are numbered; the factor it gives the published covariance
never shrinks it (the office regression is in tests/services/tools/test_localizer_edge_agreement.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.localization.refine import edge_agreement
from common.localization.search import agreement_inflation

EDGES, POINTS_PER_EDGE = 24, 8


def _design(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A Jacobian (P, 6) whose rows vary smoothly along each edge (as a projected edge's do) and each
    point's edge."""
    base = rng.normal(size=(EDGES, 6))
    slope = rng.normal(scale=0.3, size=(EDGES, 6))
    along = np.linspace(-1.0, 1.0, POINTS_PER_EDGE)
    J = (base[:, None, :] + slope[:, None, :] * along[None, :, None]).reshape(-1, 6)
    return J, np.repeat(np.arange(EDGES), POINTS_PER_EDGE)


def _agreement(J: np.ndarray, d: np.ndarray, edge: np.ndarray) -> float:
    H_inv = np.linalg.inv(J.T @ J)
    r = d - J @ (H_inv @ J.T @ d)  # the residuals at the least-squares twist
    covariance = float(r @ r) / (r.size - 6) * H_inv
    return edge_agreement(J, r, edge, H_inv, covariance)


def test_offsets_an_edges_points_share_read_high_and_scattered_ones_low() -> None:
    """Truth: 1 px of noise per point alone, or the same plus 1 px each edge's points share (what a pose
    pulled along by its edges leaves). Median over 200 draws: the clustered covariance is about as large as
    the independent one with no shared offset, and several times larger with it."""
    rng = np.random.default_rng(11)
    J, edge = _design(rng)
    scattered, shared = [], []
    for _ in range(200):
        noise = rng.normal(size=edge.size)
        scattered.append(_agreement(J, noise, edge))
        shared.append(_agreement(J, noise + np.repeat(rng.normal(size=EDGES), POINTS_PER_EDGE), edge))
    assert 0.5 < np.median(scattered) < 1.5, np.median(scattered)
    assert np.median(shared) > 3.0 * np.median(scattered), (np.median(shared), np.median(scattered))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_the_agreement_does_not_depend_on_the_numbering(seed: int) -> None:
    rng = np.random.default_rng(seed)
    J, edge = _design(rng)
    d = rng.normal(size=edge.size) + np.repeat(rng.normal(size=EDGES), POINTS_PER_EDGE)
    order, names = rng.permutation(edge.size), rng.permutation(EDGES)
    first = _agreement(J, d, edge)
    assert first > 0.0
    assert _agreement(J[order], d[order], 3 * names[edge][order]) == pytest.approx(first, rel=1e-9)


@given(r=st.floats(0.0, 100.0), reference=st.floats(0.01, 10.0), power=st.floats(0.0, 4.0))
def test_the_inflation_is_at_least_one_and_grows_with_the_agreement(
    r: float, reference: float, power: float
) -> None:
    k = agreement_inflation(r, reference, power)
    assert k >= 1.0
    assert agreement_inflation(r * 1.5 + 0.1, reference, power) >= k
    assert agreement_inflation(math.nan, reference, power) == agreement_inflation(1.0, reference, power)
