"""The fit behind the estimator's published tilt and yaw (``capataz bench consistency --fit-attitude``).

An ``attitude`` message's covariance is the filter's, with the tilt block (world x, y) times
``tilt_variance_scale`` and the yaw variance plus ``floor_rad2 + (drift_per_rad * turned)^2 +
(over_read_scale * over_read)^2`` (``PublishedUncertainty.yaw``,
:func:`services.estimator.outputs.published_attitude_covariance`).
Each attitude's terms are read from three publications of the same outputs: with the tilt scale 1, no floor,
and the yaw drift and over-read scales (1, 0), (0, 0) and (0, 1) (the differences of their yaw variances are
``turned^2`` and ``over_read^2``). :func:`common.consistency.fit_variance_terms` then fits, by maximum
likelihood on the fit seeds' whole flights:

- the tilt scale on the x and y errors of both flights together (one term: the filter's tilt variance);
- the yaw's floor, drift and over-read scale on both flights together, the filter's yaw variance a known
  part. Before the over-read term the yaw's constants were the fit of the flight that needed the larger
  variance (paper C's), which published the agile flight's yaw several times too cautious; that
  per-flight choice is reported beside the pooled fit.

A two-fold split of the fit seeds says how well each carries to seeds it was not fitted on. The held-out
seeds stay for ``bench consistency`` itself.
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
from services.estimator.outputs import PublishedUncertainty, YawChainUncertainty
from services.estimator.settings import EstimatorSettings
from services.tools.bench.consistency_runs import (
    attitude_errors,
    per_flight,
    published_messages,
    two_folds,
)

#: the yaw floor's term is this many rad^2 per unit coefficient (so the coefficients are of like size)
FLOOR_UNIT_RAD2 = 1e-6
#: the fitted constants' names (:class:`~services.estimator.outputs.PublishedUncertainty`'s tilt scale and its
#: ``yaw``'s drift, floor and over-read scale)
CONSTANTS = ("tilt_variance_scale", "yaw_drift_per_rad", "yaw_floor_rad2", "yaw_over_read_scale")


def flight_terms(flight: Flight, produced: list[AttitudeOutput | PoseOutput]) -> dict[str, FloatArray]:
    """One flight's attitude errors and terms: ``tilt_errors`` (2N,: x then y) with ``tilt_terms`` (2N, 1,
    the filter's variances), ``yaw_errors`` (N,) with ``yaw_terms`` (N, 3: ``turned^2`` in rad^2, the
    floor's unit and ``over_read^2`` in rad^2) and ``yaw_offset`` (N,: the filter's yaw variance)."""
    settings = EstimatorSettings()
    none = YawChainUncertainty(drift_per_rad=0.0, floor_rad2=0.0, over_read_scale=0.0)
    unit = replace(settings.published_uncertainty(), tilt_variance_scale=1.0, yaw=none)
    (angles, P0), (_, P_turned), (_, P_over) = (
        attitude_errors(flight, published_messages(produced, settings.max_pair_s, model))
        for model in (
            unit,
            replace(unit, yaw=replace(unit.yaw, drift_per_rad=1.0)),
            replace(unit, yaw=replace(unit.yaw, over_read_scale=1.0)),
        )
    )
    turned2 = np.maximum(P_turned[:, 2, 2] - P0[:, 2, 2], 0.0)
    over2 = np.maximum(P_over[:, 2, 2] - P0[:, 2, 2], 0.0)
    return {
        "tilt_errors": np.concatenate([angles[:, 0], angles[:, 1]]),
        "tilt_terms": np.concatenate([P0[:, 0, 0], P0[:, 1, 1]])[:, None],
        "yaw_errors": angles[:, 2],
        "yaw_terms": np.column_stack([turned2, np.full(turned2.size, FLOOR_UNIT_RAD2), over2]),
        "yaw_offset": P0[:, 2, 2],
    }


PerSeed = dict[int, dict[str, dict[str, FloatArray]]]


def _stack(per_seed: PerSeed, seeds: list[int], flights: list[str], part: str) -> list[FloatArray]:
    keys = [f"{part}_errors", f"{part}_terms"] + (["yaw_offset"] if part == "yaw" else [])
    return [np.concatenate([per_seed[s][n][k] for s in seeds for n in flights]) for k in keys]


def _variance(part: str, stacked: list[FloatArray], c: FloatArray) -> FloatArray:
    var: FloatArray = stacked[1] @ c
    return var + stacked[2] if part == "yaw" else var


def _score(per_seed: PerSeed, seeds: list[int], part: str, c: FloatArray) -> dict[str, Any]:
    """Per flight: the mean NEES per axis (tilt: of x and y each) and the share within 2 sigma."""
    scores: dict[str, Any] = {}
    for name in next(iter(per_seed.values())):
        stacked = _stack(per_seed, seeds, [name], part)
        scored = consistency(stacked[0] ** 2 / _variance(part, stacked, c), dof=1)
        scores[name] = {
            "mean_nees": round(scored.nees_mean, 3),
            "within_2_sigma": round(scored.within_2_sigma, 4),
        }
    return scores


def _fit(per_seed: PerSeed, seeds: list[int], part: str, flights: list[str]) -> FloatArray:
    """The terms' coefficients; a term the samples never reach (a short hover turns no measurable part of
    a radian at sub-pixel flow) gets 0."""
    stacked = _stack(per_seed, seeds, flights, part)
    present = np.any(stacked[1] > 0.0, axis=0)
    c = np.zeros(stacked[1].shape[1])
    c[present] = fit_variance_terms(stacked[0], stacked[1][:, present], stacked[2] if part == "yaw" else None)
    return c


def cautious_yaw_fit(per_seed: PerSeed, seeds: list[int]) -> tuple[str, FloatArray]:
    """The yaw fit of the flight whose constants give the larger variance over every flight's samples."""
    flights = list(next(iter(per_seed.values())))
    everything = _stack(per_seed, seeds, flights, "yaw")
    fits = {name: _fit(per_seed, seeds, "yaw", [name]) for name in flights}
    name = max(fits, key=lambda n: float(np.sum(_variance("yaw", everything, fits[n]))))
    return name, fits[name]


def constants(tilt: FloatArray, yaw: FloatArray) -> dict[str, float]:
    """Fitted coefficients in ``services/estimator/outputs.py``'s units."""
    values = (tilt[0], math.sqrt(float(yaw[0])), yaw[1] * FLOOR_UNIT_RAD2, math.sqrt(float(yaw[2])))
    return {name: float(f"{value:.3g}") for name, value in zip(CONSTANTS, values, strict=True)}


def _scores(per_seed: PerSeed, seeds: list[int], tilt: FloatArray, yaw: FloatArray) -> dict[str, Any]:
    return {"tilt": _score(per_seed, seeds, "tilt", tilt), "yaw": _score(per_seed, seeds, "yaw", yaw)}


def fit(seeds: list[int], frames: int | None, flights: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use, the per-flight (cautious) yaw fit and a
    two-fold split."""
    per_seed: PerSeed = {seed: per_flight(seed, frames, flights, flight_terms) for seed in seeds}
    names = list(next(iter(per_seed.values())))
    tilt = _fit(per_seed, seeds, "tilt", names)
    yaw = _fit(per_seed, seeds, "yaw", names)
    cautious_flight, cautious = cautious_yaw_fit(per_seed, seeds)
    model = PublishedUncertainty()
    in_use = (
        np.array([model.tilt_variance_scale]),
        np.array([
            model.yaw.drift_per_rad**2, model.yaw.floor_rad2 / FLOOR_UNIT_RAD2, model.yaw.over_read_scale**2
        ]),
    )  # fmt: skip
    folds = []
    for train, test in two_folds(seeds):
        c_tilt, c_yaw = _fit(per_seed, train, "tilt", names), _fit(per_seed, train, "yaw", names)
        folds.append({
            "fit_seeds": train, "scored_seeds": test, **constants(c_tilt, c_yaw),
            **_scores(per_seed, test, c_tilt, c_yaw),
        })  # fmt: skip
    return {
        "seeds": seeds,
        "frames": frames,
        "fitted": constants(tilt, yaw),
        "fitted_score": _scores(per_seed, seeds, tilt, yaw),
        "cautious_yaw_flight": cautious_flight,
        "cautious_yaw": constants(tilt, cautious),
        "cautious_yaw_score": _scores(per_seed, seeds, tilt, cautious),
        "in_use": constants(*in_use),
        "in_use_score": _scores(per_seed, seeds, *in_use),
        "two_fold": folds,
    }
