"""Demo of the localizer: a simulated flight through the built-in office, tracked by the particle filter.

Writes ``out/localizer.png`` (true vs estimated path seen from above, position and yaw error over time) and
returns a flat summary (``capataz run`` collects it into ``out/summary.json``).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from common.datasets.tum import Trajectory
from common.geometry import quaternion_from_euler
from common.localization.particle_filter import ParticleFilterSettings
from common.localization.scoring import ScoringMethod, ScoringSettings
from common.localization.tracking import track_accuracy
from common.sim.office_run import simulate_run, track_run
from services.runtime import progress
from services.runtime.trajectory import write_with_truth

logger = logging.getLogger(__name__)

#: Frames after which the filter is considered converged (RMSE is computed from here on).
SETTLE_FRAMES = 75
#: how the plots name each scoring (paper B's measures)
SCORING_TITLES = {
    ScoringMethod.KLEIN_MURRAY: "Klein-Murray edge search",
    ScoringMethod.PER_EDGE: "per-edge closeness",
    ScoringMethod.NEAREST_EDGE: "nearest-edge closeness",
    ScoringMethod.NEAREST_EDGE_DT: "nearest-edge closeness (distance transform)",
}


def _plot(
    path: Path,
    sim: Any,
    track: Any,
    accuracy: Any,
    settle: int,
    method: ScoringMethod,
    n_particles: int,
) -> Path:
    """Floor plan with the true and estimated paths; position error (cm) and yaw error (deg) on their own
    axes over flight time, with the convergence window marked."""
    truth, t = sim.flight.states, sim.flight.times_s
    figure = plt.figure(figsize=(13, 6.5))
    grid = figure.add_gridspec(2, 2, width_ratios=(1.1, 1.0))
    top = figure.add_subplot(grid[:, 0])
    position = figure.add_subplot(grid[0, 1])
    yaw = figure.add_subplot(grid[1, 1], sharex=position)
    edges = sim.scene.edges_world_m
    floor = np.abs(edges[:, :, 2]).max(axis=1) < 1e-6
    for a, b in edges[floor]:
        top.plot([a[0], b[0]], [a[1], b[1]], color="0.75", lw=0.8)
    top.plot(truth[:, 0], truth[:, 1], "k-", lw=2, label="true path")
    top.plot(track.means[:, 0], track.means[:, 1], "r--", lw=1.2, label="particle filter")
    top.plot(track.means[0, 0], track.means[0, 1], "rx", ms=8, label="initial guess")
    top.set_aspect("equal")
    top.set_xlabel("x east [m]")
    top.set_ylabel("y north [m]")
    top.set_title(f"office floor plan from above ({sim.scene.n_edges} model edges)")
    top.legend(loc="upper right", fontsize=8)
    position.plot(t, accuracy.position_errors_m * 100.0, "b-", lw=1.0)
    position.set_yscale("log")
    position.set_ylabel("position error [cm]")
    position.set_title(
        f"after convergence: position RMSE {accuracy.position_rmse_m * 100:.1f} cm, "
        f"yaw RMSE {np.degrees(accuracy.yaw_rmse_rad):.2f} deg"
    )
    yaw.plot(t, np.degrees(np.abs(accuracy.yaw_errors_rad)), "g-", lw=0.8)
    yaw.set_yscale("log")
    yaw.set_ylabel("|yaw error| [deg]")
    yaw.set_xlabel("flight time [s]")
    for ax in (position, yaw):
        ax.axvline(t[settle], color="0.4", ls=":", label=f"convergence window ({settle} frames)")
        ax.grid(alpha=0.3, which="both")
    position.legend(fontsize=8, loc="upper right")
    figure.suptitle(f"particle-filter localizer: {SCORING_TITLES[method]}, {n_particles} particles")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def run_demo(
    out_dir: Path,
    n_frames: int = 300,
    n_particles: int = 200,
    method: ScoringMethod = ScoringMethod.NEAREST_EDGE_DT,
    seed: int = 0,
) -> dict[str, Any]:
    with progress.bar(total=None, desc="localizer: rendering the office flight", unit="run") as bar:
        sim = simulate_run(n_frames=n_frames, seed=seed)
        bar.update()
    config = ParticleFilterSettings(n_particles=n_particles, scoring=ScoringSettings(method=method))
    with progress.bar(total=n_frames, desc="localizer: particle filter", unit="frame") as bar:
        # track_run iterates the images once, in order: count them as the filter consumes them
        counted = replace(sim, images=cast(Any, bar.track(sim.images)))
        track = track_run(counted, config, seed=seed + 1)
    settle = min(SETTLE_FRAMES, n_frames - 1)
    accuracy = track_accuracy(track.means, sim.flight.states, first_frame=settle)
    truth = sim.flight.states

    out_dir.mkdir(parents=True, exist_ok=True)
    path = _plot(out_dir / "localizer.png", sim, track, accuracy, settle, method, n_particles)
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
        "tum": write_with_truth(
            out_dir / "tum",
            "pose_pf",
            _trajectory(sim.flight.times_s, track.means),
            _trajectory(sim.flight.times_s, truth),
        ),
    }
    print(
        f"localizer: {n_frames} frames through '{sim.scene.name}' ({sim.scene.n_edges} edges), "
        f"{n_particles} particles, {SCORING_TITLES[method]}: after {settle} frames position RMSE "
        f"{summary['position_rmse_cm']:.2f} cm, yaw RMSE {summary['yaw_rmse_deg']:.3f} deg "
        f"(initial guess off by {summary['guess_position_error_cm']:.0f} cm and "
        f"{summary['guess_yaw_error_deg']:.1f} deg yaw); wrote {path}"
    )
    return summary


def _trajectory(stamps_s: np.ndarray, states: np.ndarray) -> Trajectory:
    """Poses (x, y, z, roll, pitch, yaw) per stamp as a TUM trajectory."""
    return Trajectory(stamps_s, states[:, :3], np.atleast_2d(quaternion_from_euler(*states[:, 3:6].T)))
