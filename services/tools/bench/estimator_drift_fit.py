"""The fit behind the estimator's published horizontal drift (``capataz bench consistency --fit-drift``).

A ``pose/vo`` message's horizontal variance is ``(drift_per_pair * H)^2 + MIN_VAR_XY_M2`` plus the unseen
motion of failed pairs, with ``H`` the camera heights of the measured pairs summed
(:func:`services.estimator.outputs.horizontal_variance`). Each tracked pose's ``H^2`` is read from two
publications of the same outputs, with ``drift_per_pair`` 1 and 0 (the difference of their variances; the
distance drift and the tilt offset off in both). :func:`common.consistency.fit_variance_terms` then fits
``drift_per_pair^2`` and the floor by maximum likelihood on the x and y errors of the fit seeds' poses of both
flights (poses with unseen motion left out), and a two-fold split of those seeds says how well the model
carries to seeds it was not fitted on. The held-out seeds stay for ``bench consistency`` itself.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from common.consistency import consistency, fit_variance_terms
from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.sim.flight import Flight
from common.types import FloatArray
from services.estimator import outputs
from services.estimator.settings import EstimatorSettings
from services.tools.bench.consistency_runs import (
    per_flight,
    position_errors,
    published_messages,
    tracked_poses,
    two_folds,
)

#: the floor's term is this many m^2 per unit coefficient (so the two coefficients are of like size)
FLOOR_UNIT_M2 = 1e-6


def flight_terms(flight: Flight, produced: list[AttitudeOutput | PoseOutput]) -> dict[str, Any]:
    """The x and y errors of one flight's tracked poses without unseen motion (2N,: x then y), their terms
    (2N, 2): ``H^2`` (m^2) and the floor's unit, and how many tracked poses were left out."""
    settings = EstimatorSettings()
    unit = replace(
        settings.published_uncertainty(), drift_fraction=0.0, level_tilt_factor=0.0, drift_per_pair=1.0
    )
    with_drift, without = (
        tracked_poses(published_messages(produced, settings.max_pair_s, model))
        for model in (unit, replace(unit, drift_per_pair=0.0))
    )
    var1 = np.array([m.covariance[0, 0] for m in with_drift])
    var0 = np.array([m.covariance[0, 0] for m in without])
    plain = np.isclose(var0, outputs.MIN_VAR_XY_M2, rtol=1e-9, atol=0.0)  # no unseen motion
    error = position_errors(flight, with_drift)[0][plain, :2]
    terms = np.column_stack([var1 - var0, np.full(var1.size, FLOOR_UNIT_M2)])[plain]
    return {"errors": error.T.ravel(), "terms": np.vstack([terms, terms]), "left_out": int(np.sum(~plain))}


def _score(per_seed: dict[int, dict[str, Any]], seeds: list[int], c: FloatArray) -> dict[str, Any]:
    """Per flight: the mean NEES of x, y (2 dof) and the share within 2 sigma with coefficients ``c``."""
    scores: dict[str, Any] = {}
    for name in next(iter(per_seed.values())):
        nees = []
        for s in seeds:
            e, terms = per_seed[s][name]["errors"], per_seed[s][name]["terms"]
            n = e.size // 2
            var = (terms @ c)[:n]
            nees.append((e[:n] ** 2 + e[n:] ** 2) / var)
        scored = consistency(np.concatenate(nees), dof=2)
        scores[name] = {
            "mean_nees": round(scored.nees_mean, 3),
            "within_2_sigma": round(scored.within_2_sigma, 4),
        }
    return scores


def _stack(per_seed: dict[int, dict[str, Any]], seeds: list[int]) -> tuple[FloatArray, FloatArray]:
    parts = [flight for s in seeds for flight in per_seed[s].values()]
    return np.concatenate([f["errors"] for f in parts]), np.vstack([f["terms"] for f in parts])


def constants(c: FloatArray) -> dict[str, float]:
    """Fitted coefficients in ``services/estimator/outputs.py``'s units."""
    return {
        "drift_per_pair": float(f"{math.sqrt(float(c[0])):.3g}"),
        "MIN_VAR_XY_M2": float(f"{c[1] * FLOOR_UNIT_M2:.3g}"),
    }


def fit(seeds: list[int], frames: int | None, flights: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use, and a two-fold split of the seeds."""
    per_seed = {seed: per_flight(seed, frames, flights, flight_terms) for seed in seeds}
    fitted = fit_variance_terms(*_stack(per_seed, seeds))
    in_use = np.array(
        [outputs.PublishedUncertainty().drift_per_pair ** 2, outputs.MIN_VAR_XY_M2 / FLOOR_UNIT_M2]
    )
    folds = []
    for train, test in two_folds(seeds):
        c = fit_variance_terms(*_stack(per_seed, train))
        folds.append({"fit_seeds": train, "scored_seeds": test, **constants(c), **_score(per_seed, test, c)})
    return {
        "seeds": seeds,
        "frames": frames,
        "left_out": {s: {n: f["left_out"] for n, f in per_seed[s].items()} for s in seeds},
        "fitted": constants(fitted),
        "fitted_score": _score(per_seed, seeds, fitted),
        "in_use": constants(in_use),
        "in_use_score": _score(per_seed, seeds, in_use),
        "two_fold": folds,
    }
