"""The fit behind the localizer's published covariance (``capataz bench consistency --fit-localizer``).

A tracked frame's covariance is the fused one (shrunk towards its diagonal by ``covariance_shrinkage``) times
``covariance_scale``, times ``max(1, r / agreement_reference) ** agreement_power`` with ``r`` the
refinement's edge agreement (:class:`~common.localization.tracker_state.TrackerSettings`). Each tracked
frame's error (:func:`~common.localization.pose.pose_errors`), its covariance with the scale 1
and no agreement term, and its ``r`` are read from one run of the tracker per scene and seed; the scale,
reference and power are then the Gaussian maximum-likelihood fit of the 6-dof errors of both scenes (the
shrinkage stays as set: it shapes the covariance, the three scale it).

The likelihood has a second, lower basin where the reference goes to 0 (a pure power of ``r``); the search
starts from the constants in use and bounds the reference's logarithm, and the two-fold split says how well
the fit carries to seeds it was not fitted on. The held-out seeds stay for ``bench consistency`` itself.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import minimize

from common.consistency import consistency, normalised_errors_squared
from common.localization.tracker_state import TrackerSettings, TrackingStatus
from common.types import FloatArray
from services.tools.bench.consistency_runs import LOCALIZER_SCENES, tracked_scene, two_folds

#: the fitted constants' names (fields of :class:`~common.localization.tracker_state.TrackerSettings`)
CONSTANTS = ("covariance_scale", "agreement_reference", "agreement_power")
#: the reference's search range (the edge agreement of a well-fitting pose is 0.2-0.45)
LOG_REFERENCE_RANGE = (math.log(0.01), math.log(10.0))

Frames = dict[str, FloatArray]


def scene_frames(name: str, seed: int, frames: int) -> Frames:
    """One run's tracked frames: ``errors`` (N, 6), ``covariances`` (N, 6, 6: scale 1, no agreement term)
    and ``agreement`` (N,; NaN counts as 1, as the tracker takes it)."""
    unit = replace(TrackerSettings(), covariance_scale=1.0, agreement_power=0.0)
    states, errors = tracked_scene(LOCALIZER_SCENES[name](frames, seed), seed, unit)
    kept = [i for i, s in enumerate(states) if s.status is TrackingStatus.TRACKING]
    agreement = np.array([states[i].edge_agreement for i in kept], dtype=np.float64)
    return {
        "errors": errors[kept].reshape(-1, 6),
        "covariances": np.array([states[i].covariance for i in kept]).reshape(-1, 6, 6),
        "agreement": np.where(np.isfinite(agreement), agreement, 1.0),
    }


PerSeed = dict[int, dict[str, Frames]]


def _stack(per_seed: PerSeed, seeds: list[int], scenes: list[str]) -> Frames:
    return {
        key: np.concatenate([per_seed[s][n][key] for s in seeds for n in scenes])
        for key in ("errors", "covariances", "agreement")
    }


def published(frames: Frames, constants: dict[str, float]) -> FloatArray:
    """The covariances the constants publish for ``frames``."""
    ratio = frames["agreement"] / constants["agreement_reference"]
    factor = constants["covariance_scale"] * np.maximum(1.0, ratio) ** constants["agreement_power"]
    return np.asarray(frames["covariances"] * factor[:, None, None], dtype=np.float64)


def _negative_log_likelihood(frames: Frames, constants: dict[str, float]) -> float:
    C = published(frames, constants)
    sign, log_det = np.linalg.slogdet(C)
    if np.any(sign <= 0):
        return math.inf
    return float(np.sum(log_det) + np.sum(normalised_errors_squared(frames["errors"], C)))


def _constants(x: FloatArray) -> dict[str, float]:
    log_ref = float(np.clip(x[1], *LOG_REFERENCE_RANGE))
    return {
        "covariance_scale": math.exp(x[0]),
        "agreement_reference": math.exp(log_ref),
        "agreement_power": float(x[2]),
    }


def fit_constants(frames: Frames, start: dict[str, float]) -> dict[str, float]:
    """Maximum likelihood of the 6-dof errors, from ``start`` (Nelder-Mead on log scale, log reference,
    power), rounded to three significant digits."""
    x0 = [
        math.log(start["covariance_scale"]),
        math.log(start["agreement_reference"]),
        start["agreement_power"],
    ]
    result = minimize(
        lambda x: _negative_log_likelihood(frames, _constants(x)),
        x0,
        method="Nelder-Mead",
        options={"maxiter": 4000, "xatol": 1e-4, "fatol": 1e-3},
    )
    return {name: float(f"{value:.3g}") for name, value in _constants(result.x).items()}


def _score(per_seed: PerSeed, seeds: list[int], constants: dict[str, float]) -> dict[str, Any]:
    """Per scene: the 6-dof mean NEES and share within 2 sigma, and the blocks' mean NEES."""
    scores: dict[str, Any] = {}
    for name in next(iter(per_seed.values())):
        frames = _stack(per_seed, seeds, [name])
        C, e = published(frames, constants), frames["errors"]
        six = consistency(normalised_errors_squared(e, C), dof=6)
        scores[name] = {
            "mean_nees": round(six.nees_mean, 3),
            "within_2_sigma": round(six.within_2_sigma, 4),
            "position_nees": round(float(np.mean(normalised_errors_squared(e[:, :3], C[:, :3, :3]))), 3),
            "rotation_nees": round(float(np.mean(normalised_errors_squared(e[:, 3:], C[:, 3:, 3:]))), 3),
        }
    return scores


def fit(seeds: list[int], frames: int, scenes: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use and a two-fold split."""
    names = scenes or list(LOCALIZER_SCENES)
    per_seed: PerSeed = {seed: {n: scene_frames(n, seed, frames) for n in names} for seed in seeds}
    settings = TrackerSettings()
    in_use = {name: float(getattr(settings, name)) for name in CONSTANTS}
    fitted = fit_constants(_stack(per_seed, seeds, names), in_use)
    folds = []
    for train, test in two_folds(seeds):
        c = fit_constants(_stack(per_seed, train, names), in_use)
        folds.append({"fit_seeds": train, "scored_seeds": test, **c, **_score(per_seed, test, c)})
    return {
        "seeds": seeds,
        "frames": frames,
        "covariance_shrinkage": settings.covariance_shrinkage,
        "fitted": fitted,
        "fitted_score": _score(per_seed, seeds, fitted),
        "in_use": in_use,
        "in_use_score": _score(per_seed, seeds, in_use),
        "two_fold": folds,
    }
