"""Demo of the localizer: a simulated flight through the built-in office, tracked by the particle filter.

Writes ``out/localizer.png`` (true vs estimated path seen from above, position and yaw error over time) and
returns a flat summary (``capataz run`` collects it into ``out/summary.json``).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from common.localization.particle_filter import ParticleFilterSettings
from common.localization.scoring import ScoringMethod, ScoringSettings
from common.localization.simulation import simulate_run, track_run
from common.localization.tracking import track_accuracy

logger = logging.getLogger(__name__)

#: Frames after which the filter is considered converged (RMSE is computed from here on).
SETTLE_FRAMES = 75


def run_demo(
    out_dir: Path,
    n_frames: int = 300,
    n_particles: int = 200,
    method: ScoringMethod = ScoringMethod.NEAREST_EDGE_DT,
    seed: int = 0,
) -> dict[str, Any]:
    sim = simulate_run(n_frames=n_frames, seed=seed)
    config = ParticleFilterSettings(n_particles=n_particles, scoring=ScoringSettings(method=method))
    track = track_run(sim, config, seed=seed + 1)
    settle = min(SETTLE_FRAMES, n_frames - 1)
    accuracy = track_accuracy(track.means, sim.flight.states, first_frame=settle)
    truth = sim.flight.states
    t = sim.flight.times_s

    out_dir.mkdir(parents=True, exist_ok=True)
    figure, (top, errors) = plt.subplots(1, 2, figsize=(13, 5.2))
    edges = sim.scene.edges_world_m
    floor = np.abs(edges[:, :, 2]).max(axis=1) < 1e-6
    for a, b in edges[floor]:
        top.plot([a[0], b[0]], [a[1], b[1]], color="0.75", lw=0.8)
    top.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="true path")
    top.plot(track.means[:, 0], track.means[:, 1], "r--", lw=1.2, label="particle filter")
    top.plot(track.means[0, 0], track.means[0, 1], "rx", ms=8, label="initial estimate")
    top.set_aspect("equal")
    top.set_xlabel("x east (m)")
    top.set_ylabel("y north (m)")
    top.set_title(f"{sim.scene.name}: {sim.scene.n_edges} edges, floor plan from above")
    top.legend(loc="upper right", fontsize=8)
    errors.plot(t, accuracy.position_errors_m * 100.0, "b-", label="position error (cm)")
    errors.plot(
        t, np.degrees(np.abs(accuracy.yaw_errors_rad)) * 10.0, "g-", lw=0.8, label="|yaw error| x 10 (deg)"
    )
    errors.axvline(t[settle], color="0.5", ls=":", label="convergence window ends")
    errors.set_yscale("log")
    errors.set_xlabel("time (s)")
    errors.set_title(
        f"{method.value}, {n_particles} particles: RMSE {accuracy.position_rmse_m * 100:.1f} cm, "
        f"yaw {np.degrees(accuracy.yaw_rmse_rad):.2f} deg"
    )
    errors.legend(fontsize=8)
    figure.tight_layout()
    path = out_dir / "localizer.png"
    figure.savefig(path, dpi=110)
    plt.close(figure)

    summary = {
        "frames": n_frames,
        "particles": n_particles,
        "scoring": method.value,
        "position_rmse_cm": accuracy.position_rmse_m * 100.0,
        "yaw_rmse_deg": float(np.degrees(accuracy.yaw_rmse_rad)),
        "guess_position_error_cm": float(np.linalg.norm(sim.guess[:3] - truth[0, :3]) * 100.0),
        "guess_yaw_error_deg": float(np.degrees(abs(sim.guess[5] - truth[0, 5]))),
        "first_estimate_position_error_cm": float(accuracy.position_errors_m[0] * 100.0),
        "settle_frames": settle,
        "reinitialisations": track.reinitialisations,
        "plot": str(path),
    }
    print(
        f"localizer: {n_frames} frames through '{sim.scene.name}' ({sim.scene.n_edges} edges), "
        f"{n_particles} particles, {method.value}: after {settle} frames position RMSE "
        f"{summary['position_rmse_cm']:.2f} cm, yaw RMSE {summary['yaw_rmse_deg']:.3f} deg "
        f"(initial guess off by {summary['guess_position_error_cm']:.0f} cm and "
        f"{summary['guess_yaw_error_deg']:.1f} deg yaw); wrote {path}"
    )
    return summary
