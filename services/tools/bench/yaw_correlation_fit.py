"""The fit of the measured yaw pairs' correlation in time (``bench consistency --fit-yaw-correlation``).

Consecutive measured pairs err alike, so the published yaw (their sum) is further off than the sum of the
pairs' variances says. :func:`common.yaw.yaw_variance.pair_covariance_rad2` models a run's pair errors as each
pair's own (published) variance, of which a share ``q`` is a Gauss-Markov error with time constant ``tau``
shared between measured pairs. This tool runs the core over the field suite's fit seeds (with and without the
gyro, as the bench does), and fits ``(q, tau)`` by the Gaussian likelihood of each run's whole error vector
(Nelder-Mead). It scores the fit, the constants in use and "independent" (``q = 0``, the model before) by the
published yaw's mean NEES and 2-sigma share at every frame, and a two-fold split of the fit seeds says how
well the pair carries to seeds it was not fitted on. The held-out seeds stay for ``bench consistency``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.consistency import consistency
from common.metrics import yaw_error_rad
from common.provenance import Provenance
from common.sim.field import FIELD_SCENARIOS, field_flight
from common.types import FloatArray
from common.yaw import YawSettings, yaw_variance
from services.tools.bench.consistency_runs import two_folds
from services.tools.bench.yaw_field import run_core

logger = logging.getLogger(__name__)

#: where the fit starts (share, time constant in s); the best of them is kept
STARTS = ((0.5, 0.2), (0.2, 1.0), (0.8, 0.05))


@dataclass(frozen=True)
class PairRun:
    """One run's pairs: errors against truth, published variances, end stamps and provenance."""

    name: str
    errors_rad: FloatArray
    variances_rad2: FloatArray
    stop_s: FloatArray
    provenance: tuple[Provenance, ...]


def pair_runs(seed: int, frames: int, scenarios: list[str] | None = None) -> list[PairRun]:
    """The runs of one seed over the field scenarios, with and without the gyro."""
    runs = []
    for name in scenarios or list(FIELD_SCENARIOS):
        flight = field_flight(name, seed=seed, n_frames=frames)
        rendered = list(flight.frames())
        for gyro in (True, False):
            series = run_core(flight, YawSettings(), rendered, gyro)
            runs.append(
                PairRun(
                    name=f"{name}{'' if gyro else ' (no imu)'}",
                    errors_rad=yaw_error_rad(series.delta_rad, np.diff(flight.yaw_rad)),
                    variances_rad2=np.asarray(series.delta_variance_rad2, dtype=np.float64),
                    stop_s=np.asarray(flight.frame_stamps_s[1:], dtype=np.float64),
                    provenance=tuple(series.provenance),
                )
            )
        logger.info("yaw correlation fit: seed %d %s done", seed, name)
    return runs


def _covariance(run: PairRun, model: yaw_variance.PairErrorModel) -> FloatArray:
    return yaw_variance.pair_covariance_rad2(run.variances_rad2, run.stop_s, run.provenance, model)


def negative_log_likelihood(runs: list[PairRun], model: yaw_variance.PairErrorModel) -> float:
    """``sum over runs of log det C + e^T C^-1 e`` (constants dropped), per pair."""
    total, pairs = 0.0, 0
    for run in runs:
        chol = np.linalg.cholesky(_covariance(run, model))
        white = np.linalg.solve(chol, run.errors_rad)
        total += 2.0 * float(np.sum(np.log(np.diag(chol)))) + float(white @ white)
        pairs += run.errors_rad.size
    return total / max(pairs, 1)


def _model(x: FloatArray) -> yaw_variance.PairErrorModel:
    """Unconstrained ``(logit share, log time)`` to a model."""
    share = float(1.0 / (1.0 + np.exp(-x[0])))
    return yaw_variance.PairErrorModel(share, float(np.clip(np.exp(x[1]), 1e-3, 1e3)))


def best_model(runs: list[PairRun]) -> yaw_variance.PairErrorModel:
    """The model of least :func:`negative_log_likelihood` (Nelder-Mead from each of :data:`STARTS`)."""
    from scipy.optimize import minimize

    best: tuple[float, yaw_variance.PairErrorModel] | None = None
    for share, time_s in STARTS:
        x0 = np.array([np.log(share / (1.0 - share)), np.log(time_s)])
        result = minimize(lambda x: negative_log_likelihood(runs, _model(x)), x0, method="Nelder-Mead",
                          options={"maxiter": 300, "xatol": 1e-3, "fatol": 1e-5})  # fmt: skip
        if best is None or result.fun < best[0]:
            best = (float(result.fun), _model(result.x))
    assert best is not None
    return best[1]


def accumulated_score(runs: list[PairRun], model: yaw_variance.PairErrorModel) -> dict[str, float]:
    """The published yaw's honesty at every frame under ``model``: its error (the pairs' errors summed)
    against its variance (the covariance's leading blocks summed)."""
    nees = []
    for run in runs:
        summed = np.cumsum(np.cumsum(_covariance(run, model), axis=0), axis=1)
        nees.append(np.cumsum(run.errors_rad) ** 2 / np.diag(summed))
    scored = consistency(np.concatenate(nees), dof=1)
    return {
        "share": round(model.correlated_share, 3),
        "time_s": round(model.correlation_time_s, 4),
        "nll_per_pair": round(negative_log_likelihood(runs, model), 4),
        "yaw_mean_nees": round(scored.nees_mean, 3),
        "yaw_within_2_sigma": round(scored.within_2_sigma, 4),
    }


def fit(seeds: list[int], frames: int, scenarios: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use, independent pairs and a two-fold split."""
    per_seed = {seed: pair_runs(seed, frames, scenarios) for seed in seeds}
    return fit_runs(per_seed, frames)


def fit_runs(per_seed: dict[int, list[PairRun]], frames: int) -> dict[str, Any]:
    """:func:`fit` of runs already made."""
    seeds = sorted(per_seed)
    runs = [run for seed in seeds for run in per_seed[seed]]
    folds = []
    for train, test in two_folds(seeds):
        model = best_model([r for s in train for r in per_seed[s]])
        folds.append({"fit_seeds": train, "scored_seeds": test,
                      **accumulated_score([r for s in test for r in per_seed[s]], model)})  # fmt: skip
    return {
        "seeds": seeds,
        "frames": frames,
        "fitted": accumulated_score(runs, best_model(runs)),
        "in_use": accumulated_score(runs, yaw_variance.PairErrorModel()),
        "independent": accumulated_score(runs, yaw_variance.PairErrorModel(0.0, 1.0)),
        "two_fold": folds,
    }
