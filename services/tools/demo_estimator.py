"""Estimator demo: paper C's flight (b) through the EKF + VO with double coupling, with and without
rectification, and the EKF with gyro-only yaw; writes ``estimator.png`` (like paper C's Figs. 13-14) and
``estimator.json``.
"""

from __future__ import annotations

import logging
import multiprocessing
import time
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.datasets.tum import Trajectory
from common.estimation.measurements import FrameMeasurement, Measurement
from common.estimation.replay import (
    CONFIGURATIONS,
    EstimatorRun,
    RunErrors,
    evaluate,
)
from common.geometry import euler_from_quaternion, wrap_angle_rad
from common.sim.comparison import compare_on_flight_b
from common.sim.flight import Flight, turns_flight
from services.runtime import progress
from services.runtime.trajectory import truth_at, write_with_truth
from services.tools.report import write_json

logger = logging.getLogger(__name__)

COLOURS = {
    "rectified": "tab:red",
    "rectified_paper_c": "tab:orange",
    "traditional": "tab:blue",
    "raw_ekf_scale": "tab:purple",
    "gyro_yaw": "tab:green",
}
LABELS = {
    "rectified": "VO on rectified frames, bias filter (double coupling)",
    "rectified_paper_c": "VO on rectified frames, paper C's 5-state EKF",
    "traditional": "VO on raw frames, rangefinder scale (traditional)",
    "raw_ekf_scale": "VO on raw frames, filter altitude scale",
    "gyro_yaw": "filter without visual yaw (gyro only)",
}


def summarize(flight: Flight, runs: dict[str, EstimatorRun], errors: dict[str, RunErrors]) -> dict[str, Any]:
    rect, trad, gyro = errors["rectified"], errors["traditional"], errors["gyro_yaw"]
    return {
        "frames": len(runs["rectified"].pose_stamps_s),
        "path_length_m": rect.path_length_m,
        "ate_rmse_cm": 100.0 * rect.ate_rmse_m,
        "ate_rmse_cm_unrectified": 100.0 * trad.ate_rmse_m,
        "ate_rmse_cm_paper_c_filter": 100.0 * errors["rectified_paper_c"].ate_rmse_m,
        "rpe_pct": rect.rpe_pct,
        "rpe_pct_unrectified": trad.rpe_pct,
        "vo_final_error_cm": 100.0 * rect.vo_final_error_m,
        "vo_error_pct": rect.vo_error_pct,
        "vo_final_error_cm_unrectified": 100.0 * trad.vo_final_error_m,
        "vo_error_pct_unrectified": trad.vo_error_pct,
        "vo_final_error_cm_raw_frames_ekf_scale": 100.0 * errors["raw_ekf_scale"].vo_final_error_m,
        "att_rmse_deg_roll_pitch_yaw": rect.att_rmse_deg.tolist(),
        "att_rmse_deg_paper_c_filter": errors["rectified_paper_c"].att_rmse_deg.tolist(),
        "alt_rmse_cm": 100.0 * rect.alt_rmse_m,
        "yaw_final_error_deg": float(abs(rect.yaw_error_deg[-1])),
        "yaw_final_error_deg_gyro_only": float(abs(gyro.yaw_error_deg[-1])),
    }


def _roll_pitch_error_deg(run: EstimatorRun, flight: Flight) -> np.ndarray:
    idx = np.searchsorted(flight.imu.stamps_s, run.attitude_stamps_s - 1e-9)
    err = euler_from_quaternion(run.q_world_body) - euler_from_quaternion(flight.imu.true_q_world_body[idx])
    return np.asarray(np.degrees(wrap_angle_rad(err))[:, :2], dtype=np.float64)


def write_estimator_tum(out_dir: Path, flight: Flight, run: EstimatorRun) -> dict[str, Any]:
    """TUM files of the attitude (position 0) and pose/vo (orientation: the attitude at the pose's stamp)
    with their ground truth at the same stamps; capataz's APE of each."""
    imu = flight.imu
    attitude = Trajectory(run.attitude_stamps_s, np.zeros((len(run.attitude_stamps_s), 3)), run.q_world_body)
    truth_q = truth_at(run.attitude_stamps_s, imu.stamps_s, np.zeros_like(imu.true_p_world_body_m),
                       imu.true_q_world_body)  # fmt: skip
    q_pose = truth_at(run.pose_stamps_s, run.attitude_stamps_s, attitude.p_world_body_m, run.q_world_body)
    pose = Trajectory(run.pose_stamps_s, run.p_world_body_m, q_pose.q_world_body)
    truth_pose = truth_at(
        run.pose_stamps_s, flight.frame_stamps_s, flight.p_world_body_m, flight.q_world_body
    )
    return {
        "attitude": write_with_truth(out_dir, "attitude", attitude, truth_q),
        "pose_vo": write_with_truth(out_dir, "pose_vo", pose, truth_pose),
    }


def plot(path: Path, flight: Flight, runs: dict[str, EstimatorRun], errors: dict[str, RunErrors]) -> Path:
    """Five panels, paper C's Figs. 13-14 and the errors behind them: the top-down path, the VO position error
    over the flight, the rectified filter's roll and pitch errors, the yaw error against gyro-only yaw, and
    the altitude with the rangefinder's readings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 12))
    grid = fig.add_gridspec(3, 2, height_ratios=(1.6, 1, 1))
    ax_xy = fig.add_subplot(grid[0, 0])
    ax_xy.plot(flight.p_world_body_m[:, 0], flight.p_world_body_m[:, 1], "k--", lw=1.2, label="truth")
    for name in ("traditional", "rectified"):
        p = runs[name].p_world_body_m
        ax_xy.plot(p[:, 0], p[:, 1], color=COLOURS[name], lw=1.0, label=LABELS[name])
    ax_xy.set(xlabel="x (m)", ylabel="y (m)", title="top-down path")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_err = fig.add_subplot(grid[0, 1])
    for name in ("traditional", "rectified_paper_c", "rectified"):
        e = errors[name]
        ax_err.plot(runs[name].pose_stamps_s, 100.0 * e.vo_error_m, color=COLOURS[name], lw=1.0,
                    label=f"{LABELS[name]}: ATE {100 * e.ate_rmse_m:.2f} cm")  # fmt: skip
    ax_err.set(xlabel="time (s)", ylabel="|VO position error| (cm)", title="visual odometry error")
    ax_tilt = fig.add_subplot(grid[1, 0])
    err = _roll_pitch_error_deg(runs["rectified"], flight)
    for k, (label, colour) in enumerate((("roll", "tab:blue"), ("pitch", "tab:orange"))):
        rms = float(np.sqrt(np.mean(err[:, k] ** 2)))
        ax_tilt.plot(runs["rectified"].attitude_stamps_s, err[:, k], color=colour, lw=0.8,
                     label=f"{label}: RMSE {rms:.3f} deg")  # fmt: skip
    ax_tilt.set(xlabel="time (s)", ylabel="error (deg)", title=f"roll and pitch error, {LABELS['rectified']}")
    ax_yaw = fig.add_subplot(grid[1, 1])
    for name in ("rectified", "gyro_yaw"):
        yaw_err = errors[name].yaw_error_deg
        rms = float(np.sqrt(np.mean(np.square(yaw_err))))
        ax_yaw.plot(runs[name].attitude_stamps_s, yaw_err, color=COLOURS[name], lw=1.0,
                    label=f"{LABELS[name]}: RMSE {rms:.3f} deg")  # fmt: skip
    ax_yaw.set(xlabel="time (s)", ylabel="yaw error (deg)", title="yaw error: visual yaw against gyro only")
    ax_alt = fig.add_subplot(grid[2, :])
    ax_alt.plot(flight.imu.stamps_s, flight.imu.true_p_world_body_m[:, 2], "k--", lw=1.2, label="truth")
    ax_alt.plot(
        flight.range.stamps_s, flight.range.range_m, ".", color="0.6", ms=2, label="rangefinder reading"
    )
    ax_alt.plot(runs["rectified"].attitude_stamps_s, runs["rectified"].pz_m, color="tab:red", lw=1.0,
                label="filter")  # fmt: skip
    ax_alt.set(xlabel="time (s)", ylabel="altitude (m)", title="altitude")
    for ax in (ax_xy, ax_err, ax_tilt, ax_yaw, ax_alt):
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=9)
    fig.suptitle(
        f"Flight (b) seed {flight.seed}: filter + visual odometry with double coupling (paper C Figs. 13-14)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


#: the configurations per process (this machine has two cores), balanced by their CPU time on flight (b):
#: rectified 8.9 s, gyro_yaw 8.4 | rectified_paper_c 7.4, raw_ekf_scale 6.7, traditional 6.2, each process
#: rendering the flight once more (6.0 s). Round-robin (3 + 2) gave the busier process 29.5 s, these 26.3 s.
#: (CPU seconds of ``compare_on_flight_b`` per configuration, ``time.process_time``, 1001 frames.)
GROUPS: tuple[tuple[str, ...], ...] = (
    ("rectified", "gyro_yaw"),
    ("rectified_paper_c", "raw_ekf_scale", "traditional"),
)

_frames_done: Any = None  # a shared counter in each worker process (set by _init_worker)


def _init_worker(counter: Any) -> None:
    global _frames_done
    _frames_done = counter


def _counted(measurements: Iterator[Measurement], weight: int) -> Iterator[Measurement]:
    """The measurements, adding ``weight`` (the estimators fed) to the shared frame counter per frame."""
    for m in measurements:
        yield m
        if isinstance(m, FrameMeasurement) and _frames_done is not None:
            with _frames_done.get_lock():
                _frames_done.value += weight


def _run_group(
    seed: int, names: tuple[str, ...], start_frame: int, stop_frame: int
) -> dict[str, EstimatorRun]:
    """One process's share: the flight rebuilt (deterministic by seed), its frames rendered once, on one
    OpenCV thread (the two processes share the two cores)."""
    cv2.setNumThreads(1)
    return compare_on_flight_b(
        seed, stop_frame - start_frame, start_frame, names, lambda stream: _counted(stream, len(names))
    )[1]


@dataclass(frozen=True)
class Started:
    """Configurations at work in their processes (:func:`start_configurations`), to be collected by
    :func:`finish_configurations`."""

    flight: Flight
    pool: ProcessPoolExecutor
    futures: list[Future[dict[str, EstimatorRun]]]
    counter: Any
    total: int

    def cancel(self) -> None:
        """Give up (the part before failed): queued work is dropped and the pool is not waited for."""
        self.pool.shutdown(wait=False, cancel_futures=True)


def start_configurations(seed: int = 0, frames: int | None = None, start_frame: int = 0) -> Started:
    """Flight (b) through every configuration of :data:`CONFIGURATIONS`, the groups in parallel processes
    (spawned: the parent may hold zenoh's threads from an earlier step); returns at once."""
    flight = turns_flight(seed=seed)
    context = multiprocessing.get_context("spawn")
    counter = context.Value("l", 0)
    stop_frame = flight.n_frames if frames is None else min(flight.n_frames, start_frame + frames)
    pool = ProcessPoolExecutor(len(GROUPS), mp_context=context, initializer=_init_worker, initargs=(counter,))
    futures = [pool.submit(_run_group, seed, group, start_frame, stop_frame) for group in GROUPS]
    return Started(flight, pool, futures, counter, (stop_frame - start_frame) * len(CONFIGURATIONS))


def finish_configurations(started: Started) -> tuple[Flight, dict[str, EstimatorRun]]:
    """Wait for the configurations with a progress bar over their frames. The results equal a
    single-process run: each configuration sees the same deterministic stream."""
    runs: dict[str, EstimatorRun] = {}
    with (
        started.pool,
        progress.bar(total=started.total, desc="estimator configurations", unit="frame") as bar,
    ):
        while not all(f.done() for f in started.futures):
            bar.set(started.counter.value)
            time.sleep(0.2)
        bar.set(started.counter.value)
        for future in started.futures:
            runs.update(future.result())
    return started.flight, {name: runs[name] for name in CONFIGURATIONS}


def run_configurations(
    seed: int = 0, frames: int | None = None, start_frame: int = 0
) -> tuple[Flight, dict[str, EstimatorRun]]:
    """:func:`start_configurations` then :func:`finish_configurations`."""
    return finish_configurations(start_configurations(seed, frames, start_frame))


def start(out_dir: Path) -> Started:
    """``capataz run`` starts this part's processes before the part ahead of it, which runs in the parent
    meanwhile (see ``services.tools.run.PRESTART``)."""
    return start_configurations()


def run_demo(out_dir: Path, started: Started | None = None) -> dict[str, Any]:
    flight, runs = finish_configurations(started if started is not None else start_configurations())
    errors = {name: evaluate(run, flight) for name, run in runs.items()}
    summary = summarize(flight, runs, errors)
    summary["tum"] = write_estimator_tum(out_dir / "tum", flight, runs["rectified"])
    png = plot(out_dir / "estimator.png", flight, runs, errors)
    write_json(out_dir / "estimator.json", summary)
    r, p, y = summary["att_rmse_deg_roll_pitch_yaw"]
    s = summary
    print(
        f"estimator: flight (b) {s['path_length_m']:.2f} m, {s['frames']} frames\n"
        f"  VO over the flight: rectified ATE {s['ate_rmse_cm']:.2f} cm, RPE {s['rpe_pct']:.3f} %/m; "
        f"raw frames ATE {s['ate_rmse_cm_unrectified']:.2f} cm, RPE {s['rpe_pct_unrectified']:.3f} %/m\n"
        f"  VO final error: rectified {s['vo_final_error_cm']:.2f} cm ({s['vo_error_pct']:.3f} %), "
        f"raw frames {s['vo_final_error_cm_unrectified']:.2f} cm ({s['vo_error_pct_unrectified']:.3f} %)\n"
        f"  filter RMSE roll {r:.3f}, pitch {p:.3f}, yaw {y:.3f} deg; altitude {s['alt_rmse_cm']:.2f} cm\n"
        f"  final yaw error: visual yaw {summary['yaw_final_error_deg']:.2f} deg, "
        f"gyro only {summary['yaw_final_error_deg_gyro_only']:.2f} deg\n"
        f"  wrote {png}"
    )
    return summary
