"""``bench consistency --fit-yaw-correlation``: the likelihood finds a known correlation, and the CLI writes
the fit with a two-fold check."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.provenance import Provenance
from common.yaw import yaw_variance
from services.tools.bench.yaw_correlation_fit import PairRun, accumulated_score, best_model
from services.tools.cli import main


def _synthetic_runs(model: yaw_variance.PairErrorModel, runs: int, seed: int = 0) -> list[PairRun]:
    """Pair errors drawn from the model itself: 20 fps, variances spread over a decade, one pair in ten
    bridged (uncorrelated)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(runs):
        n = 80
        variances = (1e-4 * 10 ** rng.uniform(-1.0, 0.0, n)) ** 2
        stops = np.cumsum(rng.uniform(0.04, 0.06, n))
        provenance = tuple(Provenance.MEASURED if u > 0.1 else Provenance.BRIDGED for u in rng.random(n))
        covariance = yaw_variance.pair_covariance_rad2(variances, stops, provenance, model)
        errors = np.linalg.cholesky(covariance) @ rng.standard_normal(n)
        out.append(PairRun(f"synthetic {k}", errors, variances, stops, provenance))
    return out


def test_the_likelihood_finds_the_model_the_errors_were_drawn_with() -> None:
    runs = _synthetic_runs(yaw_variance.PairErrorModel(0.6, 0.2), runs=40)
    fitted = best_model(runs)
    assert abs(fitted.correlated_share - 0.6) <= 0.1 and 0.2 / 1.5 <= fitted.correlation_time_s <= 0.2 * 1.5
    # and the published yaw it implies is honest on those runs, where independent pairs are not
    independent = yaw_variance.PairErrorModel(0.0, 1.0)
    assert 0.7 <= accumulated_score(runs, fitted)["yaw_mean_nees"] <= 1.4
    assert accumulated_score(runs, independent)["yaw_mean_nees"] > 2.0


def test_independent_errors_fit_no_correlation() -> None:
    fitted = best_model(_synthetic_runs(yaw_variance.PairErrorModel(0.0, 0.2), runs=40, seed=1))
    # no correlation between neighbours (a share with a vanishing time constant is none either)
    neighbours = fitted.correlated_share * np.exp(-0.05 / fitted.correlation_time_s)
    assert neighbours <= 0.1


@pytest.mark.slow
def test_the_fit_writes_its_choice_the_constants_in_use_and_a_two_fold_check(tmp_path: Path) -> None:
    code = main([
        "bench", "--out", str(tmp_path), "consistency", "--fit-yaw-correlation", "--seeds", "4",
        "--field-frames", "20", "--scenarios", "checkerboard", "field",
    ])  # fmt: skip
    assert code in (0, None)
    result = json.loads((tmp_path / "consistency.json").read_text())
    assert result["seeds"] == [0, 1] and len(result["two_fold"]) == 2
    assert 0.0 <= result["fitted"]["share"] <= 1.0 and result["fitted"]["time_s"] > 0.0
    assert result["in_use"]["share"] == round(yaw_variance.CORRELATED_SHARE, 3)
    assert result["independent"]["share"] == 0.0
    # the maximum-likelihood choice is at least as likely as the constants in use and independent pairs
    assert result["fitted"]["nll_per_pair"] <= min(
        result["in_use"]["nll_per_pair"], result["independent"]["nll_per_pair"]
    )
