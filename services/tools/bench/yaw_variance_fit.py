"""The fit behind a measured yaw pair's variance (``capataz bench consistency --fit-yaw``).

A measured pair's variance is ``RESIDUAL_SHARE * r + WARPED_FLOOR_DEG^2 * w + SHIFT_SHARE^2 * s +
AMBIGUITY_DEG^2 * a + UNREFINED_PULL^2 * u`` (:func:`common.yaw.honest.measured_variance_rad2`; each term but
``u`` per patch, times ``patches / inliers^2``; ``u`` the squared turn of a pair measured on the raw frames).
Each pair's terms ``r``, ``w``, ``s``, ``a``, ``u`` are read from five runs of the core with unit
coefficients (:data:`UNIT_TERMS`; the coefficients only scale the published variance: the pairs, their
provenance and their deltas are the same in the five runs, which is checked).
:func:`common.consistency.fit_variance_terms` then fits the coefficients by maximum likelihood on the
measured pairs of the fit seeds, and a two-fold split of those seeds (fit on one half, score the other)
says how well the model carries to seeds it was not fitted on. The held-out seeds stay for ``bench
consistency`` itself.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from typing import Any

import numpy as np

from common.consistency import consistency, fit_variance_terms
from common.metrics import yaw_error_rad
from common.provenance import Provenance
from common.sim.field import FIELD_SCENARIOS, field_flight
from common.sim.flight import Flight
from common.types import FloatArray, U8Array
from common.yaw import YawSettings, honest
from services.tools.bench.consistency_runs import two_folds
from services.tools.bench.yaw_field import run_core

logger = logging.getLogger(__name__)

#: (residual share, warp floor in deg, shift share, ambiguity in deg, unrefined pull) of the five runs: the
#: residual's term alone, then with the floor's, the shift's, the ambiguity's, the pull's (the residual's
#: stays on, so that no published variance is 0)
UNIT_TERMS = (
    (1.0, 0.0, 0.0, 0.0, 0.0),
    (1.0, 1.0, 0.0, 0.0, 0.0),
    (1.0, 0.0, 1.0, 0.0, 0.0),
    (1.0, 0.0, 0.0, 1.0, 0.0),
    (1.0, 0.0, 0.0, 0.0, 1.0),
)
#: the model's constants in its terms' order, each with the power its term scales with (the floor and the
#: ambiguity are angles, their terms per deg^2; the shift's share and the pull enter squared, the residual's
#: as it is)
_CONSTANTS = {
    "RESIDUAL_SHARE": 1,
    "WARPED_FLOOR_DEG": 2,
    "SHIFT_SHARE": 2,
    "AMBIGUITY_DEG": 2,
    "UNREFINED_PULL": 2,
}


@contextmanager
def _coefficients(*values: float) -> Iterator[None]:
    """The variance model's coefficients (in :data:`_CONSTANTS`' order) set for the block, then restored (this
    tool's runs only)."""
    saved = [getattr(honest, name) for name in _CONSTANTS]
    for name, value in zip(_CONSTANTS, values, strict=True):
        setattr(honest, name, value)
    try:
        yield
    finally:
        for name, value in zip(_CONSTANTS, saved, strict=True):
            setattr(honest, name, value)


def pair_terms(
    seed: int, frames: int, scenarios: list[str] | None = None
) -> tuple[FloatArray, FloatArray, list[str]]:
    """The measured pairs of one seed over the field scenarios, with and without the gyro: errors (N,),
    terms (N, 5) in rad^2 per unit coefficient (the floor's and the ambiguity's are in deg^2), and each pair's
    scenario."""
    errors: list[FloatArray] = []
    terms: list[FloatArray] = []
    names: list[str] = []
    for name in scenarios or list(FIELD_SCENARIOS):
        flight = field_flight(name, seed=seed, n_frames=frames)
        rendered = list(flight.frames())
        for gyro in (True, False):
            provenance, deltas, variances = unit_runs(flight, rendered, gyro, _coefficients, UNIT_TERMS)
            measured = np.array([p is Provenance.MEASURED for p in provenance])
            error = yaw_error_rad(deltas, np.diff(flight.yaw_rad))
            # each term beside the residual's: the run with its unit coefficient less the residual's run
            unit_terms = np.column_stack(
                [variances[:, 0], np.maximum(variances[:, 1:] - variances[:, :1], 0.0)]
            )
            errors.append(np.asarray(error[measured], dtype=np.float64))
            terms.append(unit_terms[measured])
            names += [name] * int(np.count_nonzero(measured))
        logger.info("yaw variance fit: seed %d %s done", seed, name)
    return np.concatenate(errors), np.vstack(terms), names


def _score(errors: FloatArray, terms: FloatArray, c: FloatArray) -> dict[str, float]:
    var = terms @ c
    nees = errors**2 / var
    scored = consistency(nees, dof=1)  # the bench's own NEES and 2-sigma share
    return {
        "pairs": scored.samples,
        "mean_nees": round(scored.nees_mean, 4),
        "within_2_sigma": round(scored.within_2_sigma, 4),
        "nll_per_pair": round(float(np.mean(np.log(var) + nees)), 4),
    }


def constants(c: FloatArray) -> dict[str, float]:
    """Fitted coefficients in ``common/yaw/honest.py``'s units."""
    return {
        name: round(float(value) ** (1.0 / power), 4 if power == 1 else 5)
        for (name, power), value in zip(_CONSTANTS.items(), c, strict=True)
    }


def coefficients_in_use() -> FloatArray:
    """The constants in ``common/yaw/honest.py`` as the terms' coefficients."""
    return np.array([getattr(honest, name) ** power for name, power in _CONSTANTS.items()], dtype=np.float64)


def fit(seeds: list[int], frames: int, scenarios: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use, and a two-fold split of the seeds."""
    per_seed = {seed: pair_terms(seed, frames, scenarios)[:2] for seed in seeds}
    return {"seeds": seeds, "frames": frames, **fit_terms(per_seed, coefficients_in_use(), constants)}


def unit_runs(
    flight: Flight,
    rendered: list[U8Array],
    gyro: bool,
    coefficients: Callable[..., AbstractContextManager[None]],
    units: Sequence[tuple[float, ...]],
) -> tuple[list[Provenance], FloatArray, FloatArray]:
    """The core over ``flight`` once per unit coefficient set (each set with ``coefficients(*unit)``): the
    pairs' provenance and deltas, the same in every run (checked: a coefficient only scales a published
    variance), and each run's published variances as a column (N, len(units))."""
    runs = []
    for unit in units:
        with coefficients(*unit):
            runs.append(run_core(flight, YawSettings(), rendered, gyro))
    provenance = [r.provenance for r in runs]
    deltas = [np.asarray(r.delta_rad) for r in runs]
    if provenance[1:] != provenance[:-1] or not all(np.array_equal(deltas[0], d) for d in deltas):
        raise RuntimeError(f"{flight.name}: the coefficients changed more than the variances")
    variances = np.column_stack([np.asarray(r.delta_variance_rad2, dtype=np.float64) for r in runs])
    return provenance[0], deltas[0], variances


def _fit_present(errors: FloatArray, terms: FloatArray, in_use: FloatArray) -> FloatArray:
    """:func:`~common.consistency.fit_variance_terms` of the terms some pair exercised; a term no pair
    exercised (no unrefined pair in a short flight) cannot be fitted and keeps its ``in_use`` coefficient."""
    present = np.any(terms > 0.0, axis=0)
    coefficients = np.array(in_use, dtype=np.float64)
    coefficients[present] = fit_variance_terms(errors, terms[:, present])
    return coefficients


def fit_terms(
    per_seed: dict[int, tuple[FloatArray, FloatArray]],
    in_use: FloatArray,
    constants: Callable[[FloatArray], dict[str, float]],
) -> dict[str, Any]:
    """Coefficients fitted by maximum likelihood on every seed's ``(errors, terms)``, their score and the
    ``in_use`` ones', and a two-fold split of the seeds (fit on one half, scored on the other)."""
    seeds = sorted(per_seed)
    errors = np.concatenate([per_seed[s][0] for s in seeds])
    terms = np.vstack([per_seed[s][1] for s in seeds])
    fitted = _fit_present(errors, terms, in_use)
    folds = []
    for train, test in two_folds(seeds):
        c = _fit_present(
            np.concatenate([per_seed[s][0] for s in train]),
            np.vstack([per_seed[s][1] for s in train]),
            in_use,
        )
        scored = _score(
            np.concatenate([per_seed[s][0] for s in test]), np.vstack([per_seed[s][1] for s in test]), c
        )
        folds.append({"fit_seeds": train, "scored_seeds": test, **constants(c), **scored})
    absent = [i for i in range(terms.shape[1]) if not np.any(terms[:, i] > 0.0)]
    if absent:
        logger.warning("no pair exercised term(s) %s: they keep the value in use", absent)
    return {
        "unexercised_terms": absent,
        "fitted": constants(fitted),
        "fitted_score": _score(errors, terms, fitted),
        "in_use": constants(in_use),
        "in_use_score": _score(errors, terms, in_use),
        "two_fold": folds,
    }
