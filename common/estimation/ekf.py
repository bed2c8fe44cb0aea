"""Attitude and altitude EKF of paper C (section III-B): state ``[q0 q1 q2 q3 pz]`` with covariance.

- Predict from the gyro (eqs. 12-15), at the IMU's own rate with each sample's true ``dt``.
- Updates: accelerometer (eq. 16), yaw as ``[cos psi, sin psi]`` (eq. 19), rangefinder (eq. 21),
  each with its analytic Jacobian and a chi-square innovation gate.
- The quaternion is ``q_world_body`` (Hamilton, scalar first, see ``common.geometry``); after every step it
  is renormalised to unit length and kept in the half-space ``q0 >= 0`` (the covariance follows the sign).

The hot path (one predict + one update at 400 Hz) expands the 4x4 quaternion algebra into Python floats
and keeps numpy for the few 5x5 covariance products; inverses of the 1x1, 2x2 and 3x3 innovation
covariances are closed form. ``capataz bench estimator`` measures it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded, check_duration
from common.errors import InputError
from common.estimation.ekf_models import (
    STANDARD_GRAVITY_M_S2,
    EkfError,
    accelerometer_model,
    check_initial,
    chi_square_quantile,
    error_angle_covariance_world,
    expected_specific_force,
    normalized_quaternion,
    propagate_quaternion,
    rangefinder_model,
    three_floats,
    transition_floats,
    transition_matrix,
    with_reset_block,
    yaw_model,
)
from common.types import FloatArray

__all__ = [
    "STANDARD_GRAVITY_M_S2",
    "AttitudeAltitudeEkf",
    "EkfError",
    "EkfSettings",
    "EkfState",
    "UpdateResult",
]


@dataclass(frozen=True)
class EkfSettings(Bounded):
    """Noise parameters and gates of the EKF (all standard deviations, SI units)."""

    gravity_m_s2: float = bounded(STANDARD_GRAVITY_M_S2, gt=0.0)
    #: Gyro white noise per sample (rad/s); enters Q through the quaternion kinematics.
    gyro_noise_rad_s: float = bounded(0.01, gt=0.0)
    #: Extra attitude random walk (rad/sqrt(s)) that absorbs the unmodelled gyro bias.
    attitude_random_walk_rad_sqrt_s: float = bounded(0.003, ge=0.0)
    #: Altitude random walk (m/sqrt(s)) of the constant-altitude model (F_s = 1).
    altitude_random_walk_m_sqrt_s: float = bounded(0.03, ge=0.0)
    #: Accelerometer noise (m/s^2) of the hover model, including unmodelled manoeuvre accelerations.
    accel_noise_m_s2: float = bounded(0.5, gt=0.0)
    #: Skip the accelerometer update when | |a| - g | exceeds this (the vehicle is accelerating).
    accel_norm_tolerance_m_s2: float = bounded(1.0, gt=0.0)
    #: Noise of each component of the yaw observation ``[cos psi, sin psi]`` (about rad for small errors).
    yaw_noise_rad: float = bounded(0.01, gt=0.0)
    #: Rangefinder noise (m).
    range_noise_m: float = bounded(0.02, gt=0.0)
    #: Probability mass inside the chi-square gate; innovations outside it are refused.
    gate_probability: float = bounded(0.9999, gt=0.5, lt=1.0)
    #: Initial standard deviations.
    initial_attitude_std_rad: float = bounded(0.05, gt=0.0)
    initial_altitude_std_m: float = bounded(0.1, gt=0.0)


@dataclass(frozen=True)
class EkfState:
    """Estimate at ``stamp_s``: unit ``q_world_body`` (q0 >= 0), altitude ``pz_m`` and the 5x5 covariance."""

    q_world_body: FloatArray
    pz_m: float
    covariance: FloatArray
    stamp_s: float

    @property
    def x(self) -> FloatArray:
        """The state vector ``[q0 q1 q2 q3 pz]``."""
        return np.append(self.q_world_body, self.pz_m)


@dataclass(frozen=True)
class UpdateResult:
    """Outcome of one measurement update: the new state, whether the gate accepted it, and its NIS."""

    state: EkfState
    accepted: bool
    nis: float


class AttitudeAltitudeEkf:
    """The paper-C EKF. Immutable: every method takes an :class:`EkfState` and returns a new one."""

    def __init__(self, settings: EkfSettings | None = None) -> None:
        self.settings = settings or EkfSettings()
        s = self.settings
        self._accel_var = s.accel_noise_m_s2**2
        self._yaw_var = s.yaw_noise_rad**2
        self._range_var = s.range_noise_m**2
        self._gyro_var = s.gyro_noise_rad_s**2
        self._attitude_rw_var = s.attitude_random_walk_rad_sqrt_s**2
        self._altitude_rw_var = s.altitude_random_walk_m_sqrt_s**2
        self._gate = {dof: chi_square_quantile(s.gate_probability, dof) for dof in (1, 2, 3)}
        self._sign_flip = np.ones((5, 5))
        self._sign_flip[4, :4] = -1.0
        self._sign_flip[:4, 4] = -1.0

    # ---- construction -----------------------------------------------------------------------------

    def initial_state(self, q_world_body: npt.ArrayLike, pz_m: float, stamp_s: float) -> EkfState:
        """A state at ``stamp_s`` with the settings' initial uncertainty."""
        qn, pz_m, stamp_s = check_initial(q_world_body, pz_m, stamp_s)
        s = self.settings
        P = np.zeros((5, 5))
        # attitude angle std theta gives quaternion std theta/2 in the three directions orthogonal to q
        qa = np.asarray(qn)
        P[:4, :4] = (0.5 * s.initial_attitude_std_rad) ** 2 * (np.eye(4) - np.outer(qa, qa))
        P[4, 4] = s.initial_altitude_std_m**2
        return EkfState(q_world_body=qa, pz_m=float(pz_m), covariance=P, stamp_s=float(stamp_s))

    def with_altitude(self, state: EkfState, pz_m: float, std_m: float) -> EkfState:
        """The state with the altitude replaced (uncorrelated, std ``std_m``): eq. 21 inverted at start."""
        P = with_reset_block(state.covariance, 4, std_m**2)
        return EkfState(state.q_world_body, float(pz_m), P, state.stamp_s)

    def attitude_covariance_world(self, state: EkfState) -> FloatArray:
        """3x3 covariance of world-frame error angles (:func:`error_angle_covariance_world`)."""
        return error_angle_covariance_world(state.q_world_body, state.covariance[:4, :4])

    def altitude_variance(self, state: EkfState) -> float:
        return float(state.covariance[4, 4])

    # ---- predict ----------------------------------------------------------------------------------

    def predict(
        self,
        state: EkfState,
        gyro_rad_s: npt.ArrayLike,
        dt_s: float,
        accel_m_s2: npt.ArrayLike | None = None,
    ) -> EkfState:
        """Gyro prediction over ``dt_s`` (paper C eqs. 1-3 with the models of eqs. 12-15); ``accel_m_s2`` is
        not used (the constant-altitude model has no inertial navigation; the error-state filter's has).

        ``Q`` maps the gyro noise through the kinematics, ``Q_q = (dt/2)^2 sigma^2 Xi(q) Xi(q)^T =
        (dt/2)^2 sigma^2 (I - q q^T)``, plus the attitude and altitude random walks.
        """
        check_duration(dt_s)
        wx, wy, wz = three_floats(gyro_rad_s)
        a, b, c = transition_floats(wx, wy, wz, dt_s)
        q_prev = state.q_world_body.tolist()
        q0, q1, q2, q3 = propagate_quaternion((q_prev[0], q_prev[1], q_prev[2], q_prev[3]), a, b, c)
        F = transition_matrix(a, b, c)
        qk = 0.25 * (dt_s * dt_s * self._gyro_var + dt_s * self._attitude_rw_var)
        qn, flipped = normalized_quaternion(q0, q1, q2, q3)
        n0, n1, n2, n3 = qn
        m0, m1, m2, m3 = -qk * n0, -qk * n1, -qk * n2, -qk * n3
        Q = np.array(
            [
                qk + m0 * n0, m0 * n1, m0 * n2, m0 * n3, 0.0,
                m1 * n0, qk + m1 * n1, m1 * n2, m1 * n3, 0.0,
                m2 * n0, m2 * n1, qk + m2 * n2, m2 * n3, 0.0,
                m3 * n0, m3 * n1, m3 * n2, qk + m3 * n3, 0.0,
                0.0, 0.0, 0.0, 0.0, dt_s * self._altitude_rw_var,
            ]
        ).reshape(5, 5)  # fmt: skip
        P = np.dot(np.dot(F, state.covariance), F.T) + Q
        if flipped:
            P *= self._sign_flip
        return EkfState(
            q_world_body=np.array(qn), pz_m=state.pz_m, covariance=P, stamp_s=state.stamp_s + dt_s
        )

    # ---- updates ----------------------------------------------------------------------------------

    def update_accelerometer(
        self,
        state: EkfState,
        accel_m_s2: npt.ArrayLike,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> UpdateResult:
        """Accelerometer update with the model of paper C eq. 16 (eqs. 4-8).

        ``motion_accel_world_m_s2`` is the vehicle's known acceleration (zero: the paper's hover model).
        Skipped (``accepted=False``, ``nis=nan``) when the specific force is far from the expected norm.
        """
        ax, ay, az = three_floats(accel_m_s2)
        s = self.settings
        f_world = expected_specific_force(
            (ax, ay, az), motion_accel_world_m_s2, s.gravity_m_s2, s.accel_norm_tolerance_m_s2
        )
        if f_world is None:
            return UpdateResult(state=state, accepted=False, nis=math.nan)
        q = state.q_world_body.tolist()
        h, Hq = accelerometer_model((q[0], q[1], q[2], q[3]), f_world)
        (h00, h01, h02, h03), (h10, h11, h12, h13), (h20, h21, h22, h23) = Hq
        H = np.array([h00, h01, h02, h03, 0.0, h10, h11, h12, h13, 0.0, h20, h21, h22, h23, 0.0]).reshape(
            3, 5
        )
        return self._update(state, (ax - h[0], ay - h[1], az - h[2]), H, self._accel_var)

    def update_yaw(self, state: EkfState, yaw_rad: float, yaw_noise_rad: float | None = None) -> UpdateResult:
        """Yaw update with the observation ``[cos psi, sin psi]`` of paper C eqs. 18-19 (eqs. 4-8).

        ``yaw_rad`` may be unwrapped (any multiple of 2 pi): only its cosine and sine enter.
        """
        if not math.isfinite(yaw_rad):
            raise InputError(f"yaw_rad must be finite, got {yaw_rad}")
        q = state.q_world_body.tolist()
        h, Hq = yaw_model((q[0], q[1], q[2], q[3]))
        (h00, h01, h02, h03), (h10, h11, h12, h13) = Hq
        H = np.array([h00, h01, h02, h03, 0.0, h10, h11, h12, h13, 0.0]).reshape(2, 5)
        var = self._yaw_var if yaw_noise_rad is None else float(yaw_noise_rad) ** 2
        return self._update(state, (math.cos(yaw_rad) - h[0], math.sin(yaw_rad) - h[1]), H, var)

    def update_range(self, state: EkfState, range_m: float) -> UpdateResult:
        """Rangefinder update with the tilt model of paper C eq. 21 (eqs. 4-8)."""
        if not (math.isfinite(range_m) and range_m > 0.0):
            raise InputError(f"range_m must be finite and > 0, got {range_m}")
        q = state.q_world_body.tolist()
        h, Hrow = rangefinder_model((q[0], q[1], q[2], q[3]), state.pz_m)
        H = np.array([Hrow])
        return self._update(state, (range_m - h,), H, self._range_var)

    def _update(
        self, state: EkfState, innovation: tuple[float, ...], H: FloatArray, variance: float
    ) -> UpdateResult:
        """Kalman gain, gate and correction, paper C eqs. 6-8, with closed-form inverses of S (m <= 3)."""
        P = state.covariance
        PHt = np.dot(P, H.T)  # (5, m)
        S = np.dot(H, PHt)
        m = len(innovation)
        Sl = S.tolist()
        if m == 1:
            (y0,) = innovation
            s00 = Sl[0][0] + variance
            if not s00 > 0.0:
                raise EkfError(f"innovation variance {s00} is not positive")
            Sinv: list[list[float]] = [[1.0 / s00]]
            Sy = [y0 / s00]
            nis = y0 * Sy[0]
        elif m == 2:
            y0, y1 = innovation
            s00, s01, s11 = Sl[0][0] + variance, 0.5 * (Sl[0][1] + Sl[1][0]), Sl[1][1] + variance
            det = s00 * s11 - s01 * s01
            if not det > 0.0:
                raise EkfError(f"innovation covariance is not positive definite (det {det})")
            inv = 1.0 / det
            i00, i01, i11 = s11 * inv, -s01 * inv, s00 * inv
            Sinv = [[i00, i01], [i01, i11]]
            Sy = [i00 * y0 + i01 * y1, i01 * y0 + i11 * y1]
            nis = y0 * Sy[0] + y1 * Sy[1]
        else:
            y0, y1, y2 = innovation
            s00, s11, s22 = Sl[0][0] + variance, Sl[1][1] + variance, Sl[2][2] + variance
            s01, s02, s12 = Sl[0][1], Sl[0][2], Sl[1][2]
            c00 = s11 * s22 - s12 * s12
            c01 = s02 * s12 - s01 * s22
            c02 = s01 * s12 - s02 * s11
            det = s00 * c00 + s01 * c01 + s02 * c02
            if not det > 0.0:
                raise EkfError(f"innovation covariance is not positive definite (det {det})")
            inv = 1.0 / det
            c11 = (s00 * s22 - s02 * s02) * inv
            c12 = (s01 * s02 - s00 * s12) * inv
            c22 = (s00 * s11 - s01 * s01) * inv
            c00 *= inv
            c01 *= inv
            c02 *= inv
            Sinv = [[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]
            Sy = [
                c00 * y0 + c01 * y1 + c02 * y2,
                c01 * y0 + c11 * y1 + c12 * y2,
                c02 * y0 + c12 * y1 + c22 * y2,
            ]
            nis = y0 * Sy[0] + y1 * Sy[1] + y2 * Sy[2]
        if not math.isfinite(nis):
            raise InputError("innovation is not finite")
        if nis > self._gate[m]:
            return UpdateResult(state=state, accepted=False, nis=nis)
        K = np.dot(PHt, np.array(Sinv))  # (5, m), eq. 6
        dx = np.dot(PHt, np.array(Sy)).tolist()  # K y, eq. 7
        P_new = P - np.dot(K, PHt.T)  # eq. 8, (I - K H) P
        q = state.q_world_body.tolist()
        qn, flipped = normalized_quaternion(q[0] + dx[0], q[1] + dx[1], q[2] + dx[2], q[3] + dx[3])
        if flipped:
            P_new *= self._sign_flip
        new = EkfState(
            q_world_body=np.array(qn), pz_m=state.pz_m + dx[4], covariance=P_new, stamp_s=state.stamp_s
        )
        return UpdateResult(state=new, accepted=True, nis=nis)
