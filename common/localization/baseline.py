"""The paper's CPU shape, kept as the benchmark's baseline: one particle at a time.

Paper B's CPU implementation renders and scores each particle in turn (its GPU version parallelises over
particles, lines and points). :func:`weigh_per_particle` does the same in a Python loop: for every particle it
culls, projects and scores that particle's edges (numpy over its own edges and points), then normalises.
It computes the same weights as :meth:`ParticleFilter.weigh` (tested), only slower.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from common.localization.particle_filter import ParticleFilter, ParticleState, normalise_log_weights
from common.localization.scoring import ImageEdges, ScoreResult


def weigh_per_particle(
    pf: ParticleFilter, state: ParticleState, edges: ImageEdges
) -> tuple[ParticleState, ScoreResult]:
    """One weighting step, particle by particle (the baseline of ``capataz bench localizer``)."""
    n = state.particles.shape[0]
    log_weight = np.empty(n)
    fit = np.empty(n)
    for i in range(n):
        result = pf.score(state.particles[i : i + 1], edges)
        log_weight[i] = result.log_weight[0]
        fit[i] = result.fit[0]
    log_weights = normalise_log_weights(state.log_weights + log_weight)
    weighed = replace(state, log_weights=log_weights, best_fit=float(np.max(fit)))
    return weighed, ScoreResult(log_weight=log_weight, fit=fit)
