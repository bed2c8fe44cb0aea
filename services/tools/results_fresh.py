"""The deterministic figures of ``make run``, recomputed in this process without the cluster.

``make run``'s summary (``out/summary.json``) comes from the cluster, the localizer and the estimator parts.
Their accuracy figures are deterministic by seed and need none of the processes:

- ``demo_cluster``: the cluster's yaw equals the in-process core's with the flight's gyro prior, frame for
  frame (``make run`` reports the difference, 0.0 deg, and the cluster tests assert it), so the core over
  paper A's hover gives the same statistics and TUM APE;
- ``demo_localizer``: the part itself (offline, 300 frames);
- ``demo_estimator``: the ``rectified`` configuration alone (the other four are fed the same measurement
  stream independently and do not change it), with the summary's figures and TUM APE of that run.

:func:`fresh_summary` returns the parts asked for, shaped like ``out/summary.json``, so
:func:`services.tools.results_render.figure_values` renders the same figures from either. The staleness test
(tests/services/tools/test_results_fresh.py) compares every marked figure in README.md and docs/*.md with it.
"""

from __future__ import annotations

import logging
from collections.abc import Collection
from dataclasses import asdict
from pathlib import Path
from typing import Any

from common.datasets.tum import Trajectory
from common.estimation.replay import evaluate
from common.metrics import yaw_error_stats
from common.sim.comparison import compare_on_flight_b
from common.sim.flight import hover_flight
from common.yaw import YawSettings
from services.runtime.trajectory import write_with_truth
from services.tools.demo_estimator import write_estimator_tum
from services.tools.demo_yaw import AME_WINDOW, track_frames

logger = logging.getLogger(__name__)

PARTS = ("demo_cluster", "demo_localizer", "demo_estimator")


def yaw_part(out_dir: Path) -> dict[str, Any]:
    """The cluster part's accuracy figures from the in-process core (paper A's hover, seed 0)."""
    flight = hover_flight(seed=0)
    run = track_frames(flight.frames(), YawSettings(), flight)
    stats = yaw_error_stats(run.yaw_rad + flight.yaw_rad[0], flight.yaw_rad, AME_WINDOW)
    stamps = flight.frame_stamps_s
    tum = write_with_truth(
        out_dir / "tum", "yaw", Trajectory.from_yaw(stamps, run.yaw_rad),
        Trajectory.from_yaw(stamps, flight.yaw_rad - flight.yaw_rad[0]),
    )  # fmt: skip
    return {**asdict(stats), "tum": tum}


def localizer_part(out_dir: Path) -> dict[str, Any]:
    """The localizer part as ``make run`` runs it."""
    from services.tools.demo_localizer import run_demo

    return run_demo(out_dir)


def estimator_part(out_dir: Path) -> dict[str, Any]:
    """The estimator part's figures of the ``rectified`` configuration (paper C's flight (b), seed 0)."""
    flight, runs = compare_on_flight_b(seed=0, names=("rectified",))
    run = runs["rectified"]
    errors = evaluate(run, flight)
    return {
        "frames": len(run.pose_stamps_s),
        "path_length_m": errors.path_length_m,
        "ate_rmse_cm": 100.0 * errors.ate_rmse_m,
        "rpe_pct": errors.rpe_pct,
        "vo_final_error_cm": 100.0 * errors.vo_final_error_m,
        "att_rmse_deg_roll_pitch_yaw": errors.att_rmse_deg.tolist(),
        "alt_rmse_cm": 100.0 * errors.alt_rmse_m,
        "tum": write_estimator_tum(out_dir / "tum", flight, run),
    }


def fresh_summary(out_dir: Path, parts: Collection[str] = PARTS) -> dict[str, Any]:
    """The deterministic figures of the ``parts`` of ``make run`` (files it writes go under ``out_dir``)."""
    makers = {"demo_cluster": yaw_part, "demo_localizer": localizer_part, "demo_estimator": estimator_part}
    unknown = set(parts) - set(makers)
    if unknown:
        raise ValueError(f"no deterministic part named {sorted(unknown)}; parts: {', '.join(PARTS)}")
    summary = {}
    for part in PARTS:
        if part in parts:
            logger.info("fresh %s", part)
            summary[part] = makers[part](out_dir)
    return summary
