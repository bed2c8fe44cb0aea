"""Estimator (paper C) on flight (b): VO with and without rectification, EKF attitude/altitude, timings.

Runs the whole simulated flight (b) (about 13.8 m, 1001 frames, 400 Hz IMU, 50 Hz rangefinder) through
four estimators fed the same stream (``common.estimation.replay.CONFIGURATIONS``): rectified VO scaled by
the EKF altitude with visual yaw (the paper's double coupling), the "traditional" VO (raw frames, scaled
by the raw rangefinder reading), raw frames scaled by the EKF altitude, and the EKF with the gyro alone
for yaw. Single-threaded OpenCV (``cv2.setNumThreads(1)``): every timing is one core's. The EKF step time
is measured separately on the flight's IMU samples (one predict + one accelerometer update).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.estimation.ekf import AttitudeAltitudeEkf
from common.estimation.replay import (
    EstimatorRun,
    RunErrors,
    evaluate,
    flight_measurements,
    run_estimators,
    standard_estimators,
    vo_with_true_attitude,
)
from common.sim.flight import Flight, turns_flight

NAME = "estimator"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="flight (b) seed")
    parser.add_argument("--start-frame", type=int, default=0, help="first frame (default 0)")
    parser.add_argument("--frames", type=int, default=None, help="only N frames (default: to the end)")
    parser.add_argument("--ekf-steps", type=int, default=20000, help="EKF steps timed")
    parser.add_argument("--cpu", type=int, default=None, help="pin the process to this CPU (Linux)")
    parser.add_argument(
        "--no-truth-vo", action="store_true", help="skip the VO-alone run with the true attitude and altitude"
    )


def time_ekf_steps(flight: Flight, n_steps: int) -> np.ndarray:
    """Wall time (us) of each ``predict + update_accelerometer`` on the flight's IMU samples."""
    ekf = AttitudeAltitudeEkf()
    imu = flight.imu
    state = ekf.initial_state(imu.true_q_world_body[0], float(imu.true_p_world_body_m[0, 2]), 0.0)
    n = min(n_steps, len(imu.stamps_s) - 1)
    gyro = [imu.gyro_rad_s[k] for k in range(n + 1)]
    accel = [imu.accel_m_s2[k] for k in range(n + 1)]
    dts = np.diff(imu.stamps_s[: n + 1]).tolist()
    out = np.empty(n)
    clock = time.perf_counter_ns
    for k in range(n):
        t0 = clock()
        state = ekf.predict(state, gyro[k + 1], dts[k])
        state = ekf.update_accelerometer(state, accel[k + 1]).state
        out[k] = (clock() - t0) * 1e-3
    return out


def compare_on_flight_b(
    seed: int = 0, frames: int | None = None, start_frame: int = 0
) -> tuple[Flight, dict[str, EstimatorRun]]:
    """Flight (b) through the three standard estimators (frames rendered once)."""
    cv2.setNumThreads(1)
    flight = turns_flight(seed=seed)
    stop = None if frames is None else start_frame + frames
    runs = run_estimators(
        standard_estimators(flight, start_frame), flight_measurements(flight, start_frame, stop)
    )
    return flight, runs


def _row(name: str, run: EstimatorRun, err: RunErrors) -> dict[str, Any]:
    return {
        "run": name,
        "vo_final_cm": 100.0 * err.vo_final_error_m,
        "vo_pct_path": err.vo_error_pct,
        "vo_max_cm": 100.0 * err.vo_max_error_m,
        "roll_rmse_deg": float(err.att_rmse_deg[0]),
        "pitch_rmse_deg": float(err.att_rmse_deg[1]),
        "yaw_rmse_deg": float(err.att_rmse_deg[2]),
        "yaw_final_deg": float(abs(err.yaw_error_deg[-1])),
        "alt_rmse_cm": 100.0 * err.alt_rmse_m,
        "vo_ms_median": float(np.median(run.vo_ms)),
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.cpu is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {int(args.cpu)})
    t0 = time.perf_counter()
    flight, runs = compare_on_flight_b(args.seed, args.frames, args.start_frame)
    errors = {name: evaluate(r, flight, args.start_frame) for name, r in runs.items()}
    ekf_us = time_ekf_steps(flight, args.ekf_steps)
    rect, trad, gyro = errors["rectified"], errors["traditional"], errors["gyro_yaw"]
    vo_ms = runs["rectified"].vo_ms[1:]  # the first frame has no pair
    rows = [_row(name, runs[name], errors[name]) for name in runs]
    truth_vo_cm = float("nan")
    if not args.no_truth_vo:
        # the VO alone, rectified with the true attitude and scaled by the true altitude: its own error
        stop = (
            flight.n_frames if args.frames is None else min(flight.n_frames, args.start_frame + args.frames)
        )
        p_vo = vo_with_true_attitude(flight, args.start_frame, stop)
        truth_vo_cm = 100.0 * float(np.linalg.norm(p_vo[-1, :2] - flight.p_world_body_m[stop - 1, :2]))
        rows.append({"run": "rectified_true_attitude_vo_only", "vo_final_cm": truth_vo_cm})
    rows.append({"run": "ekf_step_us", "vo_final_cm": float("nan"), "vo_ms_median": float("nan"),
                 "alt_rmse_cm": float("nan"), "yaw_rmse_deg": float(np.median(ekf_us))})  # fmt: skip
    from services.demo_estimator import write_estimator_tum  # the demo's TUM files, for this bench's run

    return {
        "tum": write_estimator_tum(
            Path(getattr(args, "out", "out/bench")) / "tum_estimator", flight, runs["rectified"]
        ),
        "seed": args.seed,
        "start_frame": args.start_frame,
        "frames": len(runs["rectified"].pose_stamps_s),
        "path_length_m": rect.path_length_m,
        "vo_ms_median": float(np.median(vo_ms)),
        "vo_ms_p90": float(np.percentile(vo_ms, 90)),
        "vo_ms_median_unrectified": float(np.median(runs["traditional"].vo_ms[1:])),
        "ekf_us_per_step_median": float(np.median(ekf_us)),
        "ekf_us_per_step_p90": float(np.percentile(ekf_us, 90)),
        "vo_final_error_cm": 100.0 * rect.vo_final_error_m,
        "vo_error_pct": rect.vo_error_pct,
        "vo_max_error_cm": 100.0 * rect.vo_max_error_m,
        "vo_final_error_cm_unrectified": 100.0 * trad.vo_final_error_m,
        "vo_error_pct_unrectified": trad.vo_error_pct,
        "vo_max_error_cm_unrectified": 100.0 * trad.vo_max_error_m,
        "vo_final_error_cm_true_attitude": truth_vo_cm,
        "vo_final_error_cm_raw_frames_ekf_scale": 100.0 * errors["raw_ekf_scale"].vo_final_error_m,
        "vo_error_pct_raw_frames_ekf_scale": errors["raw_ekf_scale"].vo_error_pct,
        "att_rmse_deg": float(np.max(rect.att_rmse_deg)),
        "att_rmse_deg_roll_pitch_yaw": rect.att_rmse_deg.tolist(),
        "alt_rmse_cm": 100.0 * rect.alt_rmse_m,
        "yaw_rmse_deg_gyro_only": float(gyro.att_rmse_deg[2]),
        "yaw_final_error_deg_gyro_only": float(abs(gyro.yaw_error_deg[-1])),
        "yaw_final_error_deg": float(abs(rect.yaw_error_deg[-1])),
        "wall_s": time.perf_counter() - t0,
        "table": rows,
    }
