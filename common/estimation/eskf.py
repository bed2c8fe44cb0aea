"""Error-state EKF with gyro and accelerometer bias states: paper C's observation models, EKF2-style state.

Nominal state: ``q_world_body`` (unit, q0 >= 0), altitude ``pz_m``, gyro bias ``b_g`` (rad/s, body) and
accelerometer bias ``b_a`` (m/s^2, body). Error state (10): body-frame attitude error ``dtheta``
(``q_true = q * [1, dtheta/2]``), ``dpz``, ``db_g``, ``db_a``, with a 10x10 covariance.

- Predict: the bias-corrected gyro through paper C's quaternion kinematics (eq. 12,
  :func:`~common.estimation.ekf.propagate_quaternion`); the error dynamics ``dtheta' = -[w]x dtheta - db_g``,
  constant altitude and bias random walks.
- Updates: the accelerometer (eq. 16) plus ``b_a``, the yaw ``[cos psi, sin psi]`` (eq. 19) and the
  rangefinder (eq. 21), each from the paper-C model function of :mod:`common.estimation.ekf`; their
  quaternion Jacobians become error-state Jacobians through ``dq/dtheta = 1/2 Xi(q)``. The same chi-square
  gates and accelerometer norm check as :class:`~common.estimation.ekf.AttitudeAltitudeEkf`.

Why: a constant accelerometer bias ``b`` reads as a tilt of ``b/g`` to paper C's 5-state filter (0.05 m/s^2
is 0.3 deg), and that tilt error feeds the rectification. A body-fixed bias and a world-fixed tilt error
separate as soon as the vehicle yaws, which is what these states let the filter use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.bounds import bounded
from common.errors import InputError
from common.estimation.ekf import (
    EkfSettings,
)
from common.estimation.ekf_models import (
    EkfError,
    accelerometer_model,
    check_initial,
    chi_square_quantile,
    expected_specific_force,
    normalized_quaternion,
    propagate_quaternion,
    rangefinder_model,
    three_floats,
    yaw_model,
)
from common.geometry import matrix_from_quaternion
from common.types import FloatArray

#: Error-state layout.
THETA, PZ, BG, BA = slice(0, 3), 3, slice(4, 7), slice(7, 10)
N_ERROR = 10


@dataclass(frozen=True)
class BiasEkfSettings(EkfSettings):
    """:class:`EkfSettings` plus the bias states' priors and random walks."""

    #: The gyro bias state replaces most of the attitude random walk that absorbs it in the 5-state filter.
    attitude_random_walk_rad_sqrt_s: float = bounded(0.0005, ge=0.0)
    initial_gyro_bias_std_rad_s: float = bounded(0.01, ge=0.0)
    initial_accel_bias_std_m_s2: float = bounded(0.1, ge=0.0)
    gyro_bias_walk_rad_s_sqrt_s: float = bounded(2e-5, ge=0.0)
    accel_bias_walk_m_s2_sqrt_s: float = bounded(2e-4, ge=0.0)


@dataclass(frozen=True)
class BiasEkfState:
    """Nominal state at ``stamp_s`` and the 10x10 error-state covariance (layout :data:`THETA` ...)."""

    q_world_body: FloatArray
    pz_m: float
    gyro_bias_rad_s: FloatArray
    accel_bias_m_s2: FloatArray
    covariance: FloatArray
    stamp_s: float


@dataclass(frozen=True)
class BiasUpdateResult:
    """Outcome of one update: the new state, whether the gate accepted it, and its NIS."""

    state: BiasEkfState
    accepted: bool
    nis: float


def error_jacobian(q: tuple[float, float, float, float]) -> FloatArray:
    """``dq/dtheta`` (4x3) of ``q * [1, dtheta/2]`` at ``dtheta = 0``: ``1/2 [-q_v^T; q0 I + [q_v]x]``."""
    q0, q1, q2, q3 = q
    return 0.5 * np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


class BiasAwareEkf:
    """The error-state filter. Immutable: every method takes a :class:`BiasEkfState` and returns a new one."""

    def __init__(self, settings: BiasEkfSettings | None = None) -> None:
        self.settings = settings or BiasEkfSettings()
        s = self.settings
        self._gate = {dof: chi_square_quantile(s.gate_probability, dof) for dof in (1, 2, 3)}
        self._accel_R = np.eye(3) * s.accel_noise_m_s2**2
        self._range_var = s.range_noise_m**2
        self._yaw_var = s.yaw_noise_rad**2
        # preallocated work arrays of the predict step (the filter is single-threaded)
        self._F = np.eye(N_ERROR)
        self._Q = np.zeros((N_ERROR, N_ERROR))
        self._q_dt_s = math.nan

    # ---- construction and resets --------------------------------------------------------------------

    def initial_state(self, q_world_body: npt.ArrayLike, pz_m: float, stamp_s: float) -> BiasEkfState:
        """A state at ``stamp_s``, zero biases, the settings' initial uncertainty."""
        qn, pz_m, stamp_s = check_initial(q_world_body, pz_m, stamp_s)
        s = self.settings
        diag = np.r_[
            np.full(3, s.initial_attitude_std_rad**2),
            s.initial_altitude_std_m**2,
            np.full(3, s.initial_gyro_bias_std_rad_s**2),
            np.full(3, s.initial_accel_bias_std_m_s2**2),
        ]
        return BiasEkfState(
            np.array(qn), float(pz_m), np.zeros(3), np.zeros(3), np.diag(diag), float(stamp_s)
        )

    def with_altitude(self, state: BiasEkfState, pz_m: float, std_m: float) -> BiasEkfState:
        """The state with the altitude replaced (uncorrelated, std ``std_m``): eq. 21 inverted at start."""
        P = state.covariance.copy()
        P[PZ, :] = 0.0
        P[:, PZ] = 0.0
        P[PZ, PZ] = std_m**2
        return BiasEkfState(
            state.q_world_body, float(pz_m), state.gyro_bias_rad_s, state.accel_bias_m_s2, P, state.stamp_s
        )

    # ---- read-outs ------------------------------------------------------------------------------------

    def attitude_covariance_world(self, state: BiasEkfState) -> FloatArray:
        """3x3 covariance of world-frame error angles (``R dtheta_body``)."""
        R = matrix_from_quaternion(state.q_world_body)
        C = R @ state.covariance[THETA, THETA] @ R.T
        return np.asarray(0.5 * (C + C.T), dtype=np.float64)

    def altitude_variance(self, state: BiasEkfState) -> float:
        return float(state.covariance[PZ, PZ])

    # ---- predict --------------------------------------------------------------------------------------

    def predict(self, state: BiasEkfState, gyro_rad_s: npt.ArrayLike, dt_s: float) -> BiasEkfState:
        """Bias-corrected gyro over ``dt_s``: nominal by eq. 12, covariance ``F P F^T + Q`` with
        ``F_theta_theta = I - [w dt]x``, ``F_theta_bg = -I dt``."""
        if not (dt_s >= 0.0 and math.isfinite(dt_s)):
            raise InputError(f"dt_s must be finite and >= 0, got {dt_s}")
        gx, gy, gz = three_floats(gyro_rad_s)
        bx, by, bz = state.gyro_bias_rad_s.tolist()
        wx, wy, wz = gx - bx, gy - by, gz - bz
        half = 0.5 * dt_s
        q = state.q_world_body.tolist()
        q0, q1, q2, q3 = propagate_quaternion((q[0], q[1], q[2], q[3]), half * wx, half * wy, half * wz)
        qn, _ = normalized_quaternion(q0, q1, q2, q3)
        F = self._F
        ax, ay, az = wx * dt_s, wy * dt_s, wz * dt_s
        F[0, 1], F[0, 2], F[1, 0], F[1, 2], F[2, 0], F[2, 1] = az, -ay, -az, ax, ay, -ax
        F[0, 4] = F[1, 5] = F[2, 6] = -dt_s
        P = F @ state.covariance @ F.T
        P += self._process_noise(dt_s)
        return BiasEkfState(
            np.array(qn), state.pz_m, state.gyro_bias_rad_s, state.accel_bias_m_s2, P, state.stamp_s + dt_s
        )

    def _process_noise(self, dt_s: float) -> FloatArray:
        """Diagonal ``Q`` over ``dt_s`` (cached for the last ``dt_s``: the IMU's rate is steady)."""
        if dt_s == self._q_dt_s:
            return self._Q
        s = self.settings
        q_theta = dt_s * dt_s * s.gyro_noise_rad_s**2 + dt_s * s.attitude_random_walk_rad_sqrt_s**2
        diag = np.r_[
            np.full(3, q_theta),
            dt_s * s.altitude_random_walk_m_sqrt_s**2,
            np.full(3, dt_s * s.gyro_bias_walk_rad_s_sqrt_s**2),
            np.full(3, dt_s * s.accel_bias_walk_m_s2_sqrt_s**2),
        ]
        self._Q = np.diag(diag)
        self._q_dt_s = dt_s
        return self._Q

    # ---- updates --------------------------------------------------------------------------------------

    def update_accelerometer(
        self,
        state: BiasEkfState,
        accel_m_s2: npt.ArrayLike,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> BiasUpdateResult:
        """Accelerometer: eq. 16 plus the bias, ``h = R^T (a + g e_z) + b_a``; skipped like the 5-state
        filter's when the bias-corrected specific force is far from the expected norm."""
        ax, ay, az = three_floats(accel_m_s2)
        bax, bay, baz = state.accel_bias_m_s2.tolist()
        cx, cy, cz = ax - bax, ay - bay, az - baz
        s = self.settings
        f_world = expected_specific_force(
            (cx, cy, cz), motion_accel_world_m_s2, s.gravity_m_s2, s.accel_norm_tolerance_m_s2
        )
        if f_world is None:
            return BiasUpdateResult(state, False, math.nan)
        q = state.q_world_body.tolist()
        h, _ = accelerometer_model((q[0], q[1], q[2], q[3]), f_world)
        # dh/dtheta of R^T f for q * [1, dtheta/2] is [h]x (the cross-product matrix of eq. 16's h;
        # the tests check it against the quaternion Jacobian times dq/dtheta); dh/db_a = I
        hx, hy, hz = h
        Ht = np.array([[0.0, hz, -hy], [-hz, 0.0, hx], [hy, -hx, 0.0]])  # ([h]x)^T
        P = state.covariance
        PHt = P[:, THETA] @ Ht + P[:, BA]  # (10, 3)
        S = Ht.T @ PHt[THETA] + PHt[BA] + self._accel_R
        return self._correct(state, PHt, S, (cx - hx, cy - hy, cz - hz))

    def update_yaw(
        self, state: BiasEkfState, yaw_rad: float, yaw_noise_rad: float | None = None
    ) -> BiasUpdateResult:
        """Yaw ``[cos psi, sin psi]`` of eq. 19 (``yaw_rad`` may be unwrapped)."""
        if not math.isfinite(yaw_rad):
            raise InputError(f"yaw_rad must be finite, got {yaw_rad}")
        q = state.q_world_body.tolist()
        qt = (q[0], q[1], q[2], q[3])
        h, Hq = yaw_model(qt)
        H = np.zeros((2, N_ERROR))
        H[:, THETA] = np.array(Hq) @ error_jacobian(qt)
        var = self._yaw_var if yaw_noise_rad is None else float(yaw_noise_rad) ** 2
        y = np.array([math.cos(yaw_rad) - h[0], math.sin(yaw_rad) - h[1]])
        return self._update(state, y, H, np.eye(2) * var)

    def update_range(self, state: BiasEkfState, range_m: float) -> BiasUpdateResult:
        """Rangefinder with the tilt model of eq. 21."""
        if not (math.isfinite(range_m) and range_m > 0.0):
            raise InputError(f"range_m must be finite and > 0, got {range_m}")
        q = state.q_world_body.tolist()
        qt = (q[0], q[1], q[2], q[3])
        h, Hrow = rangefinder_model(qt, state.pz_m)
        H = np.zeros((1, N_ERROR))
        H[0, THETA] = np.array(Hrow[:4]) @ error_jacobian(qt)
        H[0, PZ] = Hrow[4]
        return self._update(state, np.array([range_m - h]), H, np.array([[self._range_var]]))

    def _update(self, state: BiasEkfState, y: FloatArray, H: FloatArray, R: FloatArray) -> BiasUpdateResult:
        """Update with a dense ``H`` (range, yaw)."""
        PHt = state.covariance @ H.T
        return self._correct(state, PHt, H @ PHt + R, tuple(float(v) for v in y))

    def _correct(
        self, state: BiasEkfState, PHt: FloatArray, S: FloatArray, y: tuple[float, ...]
    ) -> BiasUpdateResult:
        """Gate, gain, ``(I - K H) P`` and injection of the error state (closed-form ``S^-1``, m <= 3)."""
        Sinv = _inverse_spd(S)
        m = len(y)
        yv = np.array(y)
        Sy = Sinv @ yv
        nis = float(yv @ Sy)
        if not math.isfinite(nis):
            raise InputError("innovation is not finite")
        if nis > self._gate[m]:
            return BiasUpdateResult(state, False, nis)
        K = PHt @ Sinv
        dx = (PHt @ Sy).tolist()
        P_new = state.covariance - K @ PHt.T
        q0, q1, q2, q3 = state.q_world_body.tolist()
        a, b, c = 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2]
        # q * [1, dtheta/2] (right product, body-frame error)
        qn, _ = normalized_quaternion(
            q0 - q1 * a - q2 * b - q3 * c,
            q1 + q0 * a + q2 * c - q3 * b,
            q2 + q0 * b + q3 * a - q1 * c,
            q3 + q0 * c + q1 * b - q2 * a,
        )
        dxa = np.array(dx)
        new = BiasEkfState(
            q_world_body=np.array(qn),
            pz_m=state.pz_m + dx[3],
            gyro_bias_rad_s=state.gyro_bias_rad_s + dxa[BG],
            accel_bias_m_s2=state.accel_bias_m_s2 + dxa[BA],
            covariance=P_new,
            stamp_s=state.stamp_s,
        )
        return BiasUpdateResult(new, True, nis)


def _inverse_spd(S: FloatArray) -> FloatArray:
    """Closed-form inverse of a 1x1, 2x2 or 3x3 innovation covariance (EkfError if not positive definite)."""
    m = S.shape[0]
    if m == 1:
        s00 = float(S[0, 0])
        if not s00 > 0.0:
            raise EkfError(f"innovation variance {s00} is not positive")
        return np.array([[1.0 / s00]])
    if m == 2:
        (s00, s01), (s10, s11) = S.tolist()
        s01 = 0.5 * (s01 + s10)
        det = s00 * s11 - s01 * s01
        if not det > 0.0:
            raise EkfError(f"innovation covariance is not positive definite (det {det})")
        return np.array([[s11, -s01], [-s01, s00]], dtype=np.float64) / float(det)
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S.tolist()
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not det > 0.0:
        raise EkfError(f"innovation covariance is not positive definite (det {det})")
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]], dtype=np.float64) / float(det)
