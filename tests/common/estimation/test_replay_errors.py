"""The replay's per-run errors split the relative error into scale (along the path) and heading (across)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.estimation.replay import EstimatorRun, evaluate
from common.sim.flight import Flight, turns_flight


def _run_from_truth(xy_transform: np.ndarray) -> tuple[EstimatorRun, Flight]:
    flight = turns_flight(seed=0)
    p = flight.p_world_body_m.copy()
    p[:, :2] = p[:, :2] @ xy_transform.T
    imu = flight.imu
    run = EstimatorRun(
        attitude_stamps_s=imu.stamps_s,
        q_world_body=imu.true_q_world_body,
        pz_m=imu.true_p_world_body_m[:, 2],
        pose_stamps_s=flight.frame_stamps_s,
        p_world_body_m=p,
        vo_yaw_rad=flight.yaw_rad,
        rectification_weight=np.ones(flight.n_frames),
    )
    return run, flight


def test_a_scaled_path_errs_along_it_and_a_rotated_path_across_it() -> None:
    scaled, flight = _run_from_truth(np.eye(2) * 1.003)
    err = evaluate(scaled, flight)
    assert err.rpe_along_pct == pytest.approx(0.3, rel=0.05)  # 0.3 % of each metre, along it
    assert err.rpe_cross_pct == pytest.approx(0.0, abs=1e-9)
    angle = math.radians(0.2)
    c, s = math.cos(angle), math.sin(angle)
    rotated, _ = _run_from_truth(np.array([[c, -s], [s, c]]))
    err = evaluate(rotated, flight)
    assert err.rpe_cross_pct == pytest.approx(100.0 * s, rel=0.05)  # 0.35 % across: a heading error
    assert err.rpe_along_pct < 0.01
    # the along and across parts make up the RPE's pair errors
    assert err.rpe_along_pct**2 + err.rpe_cross_pct**2 <= (err.rpe_pct * 1.2) ** 2
    assert err.att_rmse_deg.max() < 1e-6
