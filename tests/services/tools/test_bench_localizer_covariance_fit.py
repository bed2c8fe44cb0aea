"""The localizer covariance fit (``bench consistency --fit-localizer``) recovers the constants errors were
drawn with: maximum likelihood of 6-dof errors under ``scale * max(1, r / reference) ** power * P``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.tools.bench.localizer_covariance_fit import fit_constants, published


def _frames(seed: int, truth: dict[str, float], n: int = 3000) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, 6, 6)) * rng.uniform(0.01, 0.1, size=(n, 1, 6))
    P = A @ A.transpose(0, 2, 1) + 1e-6 * np.eye(6)  # correlated, as the fused covariances are
    frames = {"covariances": P, "agreement": rng.lognormal(np.log(0.3), 1.0, size=n)}
    C = published({**frames, "errors": np.zeros((n, 6))}, truth)
    frames["errors"] = np.einsum("nij,nj->ni", np.linalg.cholesky(C), rng.normal(size=(n, 6)))
    return frames


@settings(max_examples=5, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    scale=st.floats(0.01, 1.0),
    reference=st.floats(0.1, 0.6),
    power=st.floats(0.5, 1.5),
)
def test_the_fit_recovers_the_constants_the_errors_were_drawn_with(
    seed: int, scale: float, reference: float, power: float
) -> None:
    truth = {"covariance_scale": scale, "agreement_reference": reference, "agreement_power": power}
    start = {"covariance_scale": 0.05, "agreement_reference": 0.2, "agreement_power": 1.0}
    fitted = fit_constants(_frames(seed, truth), start)
    assert fitted["covariance_scale"] == pytest.approx(scale, rel=0.15)
    assert fitted["agreement_power"] == pytest.approx(power, abs=0.2)
    assert fitted["agreement_reference"] == pytest.approx(reference, rel=0.35)
