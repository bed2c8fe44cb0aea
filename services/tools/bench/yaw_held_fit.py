"""The fit of a held yaw pair's variance (``capataz bench consistency --fit-yaw-held``).

Without a gyro a pair the camera cannot measure holds the recent rate (``HELD``), published with the variance
of :func:`common.yaw.honest.held_variance_terms` times :func:`common.yaw.honest.held_coefficients`. The field
suite holds almost no pair, so its frames are washed out as ``bench consistency --glare`` does (the share
given); each held pair's terms are read from three runs of the core with unit coefficients (the variance
does not gate, so the pairs, their provenance and deltas are the same in the three runs, which is checked),
and :func:`common.consistency.fit_variance_terms` fits the coefficients by maximum likelihood on the fit
seeds' held pairs, with a two-fold split of them. The held-out seeds stay for ``bench consistency``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from common.metrics import yaw_error_rad
from common.provenance import Provenance
from common.sim.field import FIELD_SCENARIOS, field_flight
from common.types import FloatArray
from common.yaw import honest
from services.tools.bench.consistency_runs import with_glare
from services.tools.bench.yaw_variance_fit import fit_terms, unit_runs

logger = logging.getLogger(__name__)

#: (spread share, acceleration in deg/s^2, rate floor in deg/s) of the three runs: each term alone at a unit
#: coefficient (1 rad^2/s^4 and 1 rad^2/s^2 for the second and third)
UNIT_TERMS = ((1.0, 0.0, 0.0), (0.0, math.degrees(1.0), 0.0), (0.0, 0.0, math.degrees(1.0)))


@contextmanager
def _coefficients(spread_share: float, accel_deg_s2: float, rate_deg_s: float) -> Iterator[None]:
    """The held variance's coefficients set for the block, then restored (this tool's runs only)."""
    saved = (honest.HELD_SPREAD_SHARE, honest.HELD_ACCEL_DEG_S2, honest.HELD_RATE_DEG_S)
    honest.HELD_SPREAD_SHARE, honest.HELD_ACCEL_DEG_S2, honest.HELD_RATE_DEG_S = (
        spread_share, accel_deg_s2, rate_deg_s
    )  # fmt: skip
    try:
        yield
    finally:
        honest.HELD_SPREAD_SHARE, honest.HELD_ACCEL_DEG_S2, honest.HELD_RATE_DEG_S = saved


def held_terms(
    seed: int, frames: int, glare: float, scenarios: list[str] | None = None
) -> tuple[FloatArray, FloatArray]:
    """The held pairs of one seed over the field scenarios (no gyro, ``glare`` of the frames washed out) that
    had a rate to hold (a measured pair before them): errors (N,) and terms (N, 3) per unit coefficient."""
    errors: list[FloatArray] = []
    terms: list[FloatArray] = []
    names = list(FIELD_SCENARIOS)
    for name in scenarios or names:
        flight = field_flight(name, seed=seed, n_frames=frames)
        rendered = with_glare(list(flight.frames()), glare, seed, names.index(name))
        provenance, deltas, variances = unit_runs(flight, rendered, False, _coefficients, UNIT_TERMS)
        held = np.array([p is Provenance.HELD for p in provenance])
        # a pair held before any was measured has no rate to hold (the uninformative prior, not this model)
        measured_before = np.concatenate([[0], np.cumsum(~held)[:-1]]) > 0
        held &= measured_before
        error = yaw_error_rad(deltas, np.diff(flight.yaw_rad))
        errors.append(np.asarray(error[held], dtype=np.float64))
        terms.append(variances[held])
        logger.info("yaw held fit: seed %d %s done", seed, name)
    return np.concatenate(errors), np.vstack(terms)


def constants(c: FloatArray) -> dict[str, float]:
    """Fitted coefficients in ``common/yaw/honest.py``'s units."""
    return {
        "HELD_SPREAD_SHARE": round(float(c[0]), 4),
        "HELD_ACCEL_DEG_S2": round(math.degrees(math.sqrt(float(c[1]))), 3),
        "HELD_RATE_DEG_S": round(math.degrees(math.sqrt(float(c[2]))), 4),
    }


def fit(seeds: list[int], frames: int, glare: float, scenarios: list[str] | None = None) -> dict[str, Any]:
    """Fit on ``seeds``; score the fit, the constants in use, and a two-fold split of the seeds."""
    per_seed = {seed: held_terms(seed, frames, glare, scenarios) for seed in seeds}
    in_use = honest.held_coefficients()
    return {"seeds": seeds, "frames": frames, "glare": glare, **fit_terms(per_seed, in_use, constants)}
