"""The model tracker's motion model: a constant-velocity Kalman filter on the camera pose.

State: camera centre ``p`` (world, m), velocity ``v`` (m/s), orientation ``R_world_camera`` and angular rate
``w`` (world frame, rad/s; ``R(t + dt) = Exp(w dt) R(t)``). The error state is 12-D:
``(dp, dv, dtheta, dw)`` with ``R_true = Exp(dtheta) R``.

Process noise is white acceleration and angular acceleration with spectral densities ``acceleration_m_s2**2``
(m^2/s^3) and ``angular_acceleration_rad_s2**2`` (rad^2/s^3): per axis over ``dt`` the discrete covariance of
(position, velocity) is ``q [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` (the continuous white-noise-acceleration
model, Bar-Shalom et al. 2001, sec. 6.2.2), likewise for (angle, rate).

The measurement is a refined pose from the images with its 6x6 covariance (centre, world error angles). An
update whose normalised innovation exceeds ``gate`` is not applied (:class:`MotionUpdate.rejected`): a single
frame's refinement can snap to a parallel edge, which the motion model then rides over.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.bounds import Bounded, bounded, check_duration
from common.errors import InputError
from common.localization.pose import CameraPose, perturb, rotation_vectors
from common.types import FloatArray


@dataclass(frozen=True)
class MotionSettings(Bounded):
    """Process noise (physical units) and the innovation gate (chi-square, 6 degrees of freedom)."""

    acceleration_m_s2: float = bounded(2.0, gt=0.0)
    angular_acceleration_rad_s2: float = bounded(float(np.radians(60.0)), gt=0.0)
    gate: float = bounded(40.0, gt=0.0)


@dataclass(frozen=True)
class MotionState:
    """Pose, velocity, angular rate and the 12x12 covariance of ``(dp, dv, dtheta, dw)``."""

    p_world_camera_m: FloatArray
    velocity_m_s: FloatArray
    R_world_camera: FloatArray
    angular_rate_rad_s: FloatArray
    covariance: FloatArray

    @property
    def pose(self) -> CameraPose:
        return CameraPose(self.p_world_camera_m, self.R_world_camera)


@dataclass(frozen=True)
class MotionUpdate:
    """The state after an update, the innovation's normalised squared distance, and whether it was gated."""

    state: MotionState
    nis: float
    rejected: bool


def motion_start(
    pose: CameraPose,
    pose_covariance: FloatArray,
    speed_m_s: float,
    rate_rad_s: float,
    velocity_m_s: FloatArray | None = None,
    angular_rate_rad_s: FloatArray | None = None,
) -> MotionState:
    """A state at ``pose`` (6x6 covariance of centre and error angles), at rest (or at the given velocity
    and world-frame rate) with a velocity and rate uncertainty of ``speed_m_s`` and ``rate_rad_s`` (1 sigma
    per axis)."""
    cov = np.zeros((12, 12))
    cov[np.ix_([0, 1, 2, 6, 7, 8], [0, 1, 2, 6, 7, 8])] = pose_covariance
    cov[3:6, 3:6] = np.eye(3) * speed_m_s**2
    cov[9:12, 9:12] = np.eye(3) * rate_rad_s**2
    v = np.zeros(3) if velocity_m_s is None else np.asarray(velocity_m_s, dtype=np.float64).copy()
    w = np.zeros(3) if angular_rate_rad_s is None else np.asarray(angular_rate_rad_s, dtype=np.float64).copy()
    return MotionState(pose.p_world_camera_m.copy(), v, pose.R_world_camera.copy(), w, cov)


def motion_predict(state: MotionState, dt_s: float, settings: MotionSettings) -> MotionState:
    """Constant velocity and angular rate over ``dt_s`` with white (angular) acceleration noise."""
    check_duration(dt_s)
    F = np.eye(12)
    F[0:3, 3:6] = np.eye(3) * dt_s
    F[6:9, 9:12] = np.eye(3) * dt_s
    block = np.array([[dt_s**3 / 3.0, dt_s**2 / 2.0], [dt_s**2 / 2.0, dt_s]])
    Q = np.zeros((12, 12))
    for offset, q in ((0, settings.acceleration_m_s2**2), (6, settings.angular_acceleration_rad_s2**2)):
        for axis in range(3):
            idx = [offset + axis, offset + 3 + axis]
            Q[np.ix_(idx, idx)] = q * block
    cov = F @ state.covariance @ F.T + Q
    return MotionState(
        state.p_world_camera_m + state.velocity_m_s * dt_s,
        state.velocity_m_s,
        perturb(state.R_world_camera[None], (state.angular_rate_rad_s * dt_s)[None])[0],
        state.angular_rate_rad_s,
        0.5 * (cov + cov.T),
    )


def motion_update(
    state: MotionState, measured: CameraPose, measured_covariance: FloatArray, settings: MotionSettings
) -> MotionUpdate:
    """Kalman update with a measured pose (6x6 covariance of centre and world error angles); gated."""
    residual = np.concatenate(
        [
            measured.p_world_camera_m - state.p_world_camera_m,
            rotation_vectors((measured.R_world_camera @ state.R_world_camera.T)[None])[0],
        ]
    )
    rows = [0, 1, 2, 6, 7, 8]
    H = np.zeros((6, 12))
    H[np.arange(6), rows] = 1.0
    S = H @ state.covariance @ H.T + measured_covariance
    try:
        S_inv = np.asarray(np.linalg.inv(S), dtype=np.float64)
    except np.linalg.LinAlgError:
        return MotionUpdate(state, float("inf"), True)
    nis = float(residual @ S_inv @ residual)
    if not np.isfinite(nis) or nis > settings.gate:
        return MotionUpdate(state, nis, True)
    return MotionUpdate(_corrected(state, residual, H, S_inv, measured_covariance), nis, False)


def motion_rate_update(
    state: MotionState, rate_world_rad_s: FloatArray, rate_sigma_rad_s: float
) -> MotionState:
    """Kalman update of the angular rate with a measured one (a gyro's mean over the frame interval,
    turned into the world frame; ``rate_sigma_rad_s`` per axis: its noise and unknown bias)."""
    rate = np.asarray(rate_world_rad_s, dtype=np.float64)
    if rate.shape != (3,) or not np.all(np.isfinite(rate)):
        raise InputError("the angular rate must be 3 finite numbers")
    if not (np.isfinite(rate_sigma_rad_s) and rate_sigma_rad_s > 0.0):
        raise InputError(f"rate_sigma_rad_s must be positive, got {rate_sigma_rad_s}")
    H = np.zeros((3, 12))
    H[:, 9:12] = np.eye(3)
    R_meas = np.eye(3) * rate_sigma_rad_s**2
    S_inv = np.asarray(np.linalg.inv(H @ state.covariance @ H.T + R_meas), dtype=np.float64)
    return _corrected(state, rate - state.angular_rate_rad_s, H, S_inv, R_meas)


def _corrected(
    state: MotionState, residual: FloatArray, H: FloatArray, S_inv: FloatArray, noise: FloatArray
) -> MotionState:
    """The Kalman correction with gain ``K = P H^T S^-1``; Joseph-form covariance."""
    K = state.covariance @ H.T @ S_inv
    dx = K @ residual
    I_KH = np.eye(12) - K @ H
    cov = I_KH @ state.covariance @ I_KH.T + K @ noise @ K.T
    return MotionState(
        state.p_world_camera_m + dx[0:3],
        state.velocity_m_s + dx[3:6],
        perturb(state.R_world_camera[None], dx[6:9][None])[0],
        state.angular_rate_rad_s + dx[9:12],
        0.5 * (cov + cov.T),
    )
