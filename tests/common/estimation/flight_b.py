"""Either attitude/altitude filter run over flight (b) of the simulator, for the filters' accuracy tests."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.geometry import euler_from_quaternion, wrap_angle_rad
from common.sim.sensors import ImuNoise, RangeNoise, sample_stamps, simulate_imu, simulate_range
from common.sim.trajectory import turns_trajectory


@dataclass(frozen=True)
class FlightRun:
    """Roll, pitch, yaw errors (deg) and altitude errors (m) at every IMU sample, the final state, the IMU."""

    errors_deg: np.ndarray
    altitude_errors_m: np.ndarray
    state: Any
    imu: Any


def run_over_flight_b(
    ekf: Any, seed: int = 0, duration_s: float = 30.0, visual_yaw: bool = True
) -> FlightRun:
    """``ekf`` over the first ``duration_s`` of flight (b) from the simulated IMU and rangefinder, the
    manoeuvre acceleration of the trajectory and (optionally) yaw readings of 0.3 deg noise at 20 Hz."""
    trajectory = turns_trajectory(seed=seed)
    imu = simulate_imu(trajectory, sample_stamps(duration_s, 400.0), ImuNoise(), seed=seed)
    rng = simulate_range(trajectory, sample_stamps(duration_s, 50.0), RangeNoise(), seed=seed)
    truth = trajectory.sample(imu.stamps_s)
    q_true = imu.true_q_world_body
    state = ekf.initial_state(q_true[0], float(rng.true_pz_m[0]), 0.0)
    noise = np.random.default_rng(5).normal(0.0, math.radians(0.3), len(imu.stamps_s))
    errors, altitude_errors = [], []
    j = 0
    for k, t in enumerate(imu.stamps_s):
        if k > 0:
            state = ekf.predict(state, imu.gyro_rad_s[k], float(t - imu.stamps_s[k - 1]))
        a = truth.a_world_m_s2[k]
        state = ekf.update_accelerometer(
            state, imu.accel_m_s2[k], (float(a[0]), float(a[1]), float(a[2]))
        ).state
        while j < len(rng.stamps_s) and rng.stamps_s[j] <= t:
            state = ekf.update_range(state, float(rng.range_m[j])).state
            j += 1
        if visual_yaw and k % 20 == 0:
            state = ekf.update_yaw(state, float(truth.euler_rad[k, 2] + noise[k])).state
        errors.append(
            wrap_angle_rad(euler_from_quaternion(state.q_world_body) - euler_from_quaternion(q_true[k]))
        )
        altitude_errors.append(state.pz_m - truth.p_world_body_m[k, 2])
    return FlightRun(np.degrees(np.array(errors)), np.array(altitude_errors), state, imu)
