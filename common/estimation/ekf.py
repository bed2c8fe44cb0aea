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

from common.errors import CapatazError, InputError
from common.geometry import check_quaternion
from common.types import FloatArray

#: Standard gravity used by the accelerometer model (m/s^2).
STANDARD_GRAVITY_M_S2 = 9.80665


class EkfError(CapatazError):
    """The filter cannot continue (non-finite state or a singular innovation covariance)."""


@dataclass(frozen=True)
class EkfSettings:
    """Noise parameters and gates of the EKF (all standard deviations, SI units)."""

    gravity_m_s2: float = STANDARD_GRAVITY_M_S2
    #: Gyro white noise per sample (rad/s); enters Q through the quaternion kinematics.
    gyro_noise_rad_s: float = 0.01
    #: Extra attitude random walk (rad/sqrt(s)) that absorbs the unmodelled gyro bias.
    attitude_random_walk_rad_sqrt_s: float = 0.003
    #: Altitude random walk (m/sqrt(s)) of the constant-altitude model (F_s = 1).
    altitude_random_walk_m_sqrt_s: float = 0.03
    #: Accelerometer noise (m/s^2) of the hover model, including unmodelled manoeuvre accelerations.
    accel_noise_m_s2: float = 0.5
    #: Skip the accelerometer update when | |a| - g | exceeds this (the vehicle is accelerating).
    accel_norm_tolerance_m_s2: float = 1.0
    #: Noise of each component of the yaw observation ``[cos psi, sin psi]`` (about rad for small errors).
    yaw_noise_rad: float = 0.01
    #: Rangefinder noise (m).
    range_noise_m: float = 0.02
    #: Probability mass inside the chi-square gate; innovations outside it are refused.
    gate_probability: float = 0.9999
    #: Initial standard deviations.
    initial_attitude_std_rad: float = 0.05
    initial_altitude_std_m: float = 0.1

    def __post_init__(self) -> None:
        for name in (
            "gravity_m_s2",
            "gyro_noise_rad_s",
            "accel_noise_m_s2",
            "accel_norm_tolerance_m_s2",
            "yaw_noise_rad",
            "range_noise_m",
            "initial_attitude_std_rad",
            "initial_altitude_std_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise InputError(f"EkfSettings.{name} must be a positive finite number, got {value}")
        for name in ("attitude_random_walk_rad_sqrt_s", "altitude_random_walk_m_sqrt_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InputError(f"EkfSettings.{name} must be >= 0, got {value}")
        if not 0.5 < self.gate_probability < 1.0:
            raise InputError(f"EkfSettings.gate_probability must be in (0.5, 1), got {self.gate_probability}")


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


# --------------------------------------------------------------------------------------------------
# Paper equations, one function each.
# --------------------------------------------------------------------------------------------------


def quaternion_rate_matrix(gyro_rad_s: npt.ArrayLike) -> FloatArray:
    """``Omega(w)`` of the quaternion kinematics ``q' = 1/2 Omega(w) q``, paper C eq. 14 (and eq. 11).

    With the gyro in the body frame this is the right product ``q * [0, w]`` of ``q_world_body``.
    """
    wx, wy, wz = (float(v) for v in np.asarray(gyro_rad_s, dtype=np.float64).reshape(3))
    return np.array(
        [
            [0.0, -wx, -wy, -wz],
            [wx, 0.0, wz, -wy],
            [wy, -wz, 0.0, wx],
            [wz, wy, -wx, 0.0],
        ]
    )


def state_transition(gyro_rad_s: npt.ArrayLike, dt_s: float) -> FloatArray:
    """5x5 transition ``F = blockdiag(F_q, F_s)``, ``F_q = 1/2 Omega(w) dt + I`` (Omega of eq. 14),
    ``F_s = 1``: paper C eqs. 13, 15."""
    wx, wy, wz = _three_floats(np.asarray(gyro_rad_s, dtype=np.float64))
    return _transition_matrix(*_transition_floats(wx, wy, wz, dt_s))


def _transition_matrix(a: float, b: float, c: float) -> FloatArray:
    """``F`` of :func:`state_transition` from ``a, b, c = dt/2 * (wx, wy, wz)`` (the hot path's form)."""
    return np.array(
        [
            1.0,
            -a,
            -b,
            -c,
            0.0,
            a,
            1.0,
            c,
            -b,
            0.0,
            b,
            -c,
            1.0,
            a,
            0.0,
            c,
            b,
            -a,
            1.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
        ]
    ).reshape(5, 5)


def _transition_floats(wx: float, wy: float, wz: float, dt_s: float) -> tuple[float, float, float]:
    """The three distinct entries ``dt/2 * w`` of ``F_q - I`` (eq. 13), for the expanded hot path."""
    half_dt = 0.5 * dt_s
    return half_dt * wx, half_dt * wy, half_dt * wz


def propagate_quaternion(
    q: tuple[float, float, float, float], a: float, b: float, c: float
) -> tuple[float, float, float, float]:
    """Discrete quaternion kinematics ``q_k = (1/2 Omega(w_k) dt + I) q_{k-1}``, paper C eq. 12.

    ``a, b, c = dt/2 * (wx, wy, wz)``; the rows are those of ``Omega`` (eq. 14) expanded.
    """
    q0, q1, q2, q3 = q
    return (
        q0 - a * q1 - b * q2 - c * q3,
        a * q0 + q1 + c * q2 - b * q3,
        b * q0 - c * q1 + q2 + a * q3,
        c * q0 + b * q1 - a * q2 + q3,
    )


def accelerometer_model(
    q: tuple[float, float, float, float], specific_force_world_m_s2: tuple[float, float, float]
) -> tuple[tuple[float, float, float], tuple[tuple[float, float, float, float], ...]]:
    """Accelerometer observation ``g^b = R_n^b g^n`` and its 3x4 Jacobian: paper C eq. 16.

    ``g^n`` is the specific force in the world frame: ``[0 0 g]`` at hover or constant velocity, which
    reduces the rows to the printed eq. 16, ``g [2(q1q3 - q2q0), 2(q2q3 + q1q0), q0^2 - q1^2 - q2^2 + q3^2]``.
    A known manoeuvre acceleration ``a`` enters as ``g^n = a + [0 0 g]`` (the coupling in
    :mod:`common.estimation.coupling` takes ``a`` from the visual odometry).
    """
    q0, q1, q2, q3 = q
    fx, fy, fz = specific_force_world_m_s2
    h = (
        (q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) * fx
        + 2.0 * (q1 * q2 + q0 * q3) * fy
        + 2.0 * (q1 * q3 - q0 * q2) * fz,
        2.0 * (q1 * q2 - q0 * q3) * fx
        + (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3) * fy
        + 2.0 * (q2 * q3 + q0 * q1) * fz,
        2.0 * (q1 * q3 + q0 * q2) * fx
        + 2.0 * (q2 * q3 - q0 * q1) * fy
        + (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3) * fz,
    )
    fx2, fy2, fz2 = 2.0 * fx, 2.0 * fy, 2.0 * fz
    a = q0 * fx2 + q3 * fy2 - q2 * fz2
    b = q1 * fx2 + q2 * fy2 + q3 * fz2
    c = -q2 * fx2 + q1 * fy2 - q0 * fz2
    d = -q3 * fx2 + q0 * fy2 + q1 * fz2
    H = ((a, b, c, d), (d, -c, b, -a), (-c, -d, a, b))
    return h, H


def yaw_model(
    q: tuple[float, float, float, float],
) -> tuple[tuple[float, float], tuple[tuple[float, float, float, float], ...]]:
    """Yaw observation ``psi_a = [cos psi, sin psi]`` and its 2x4 Jacobian: paper C eqs. 17-19.

    Eq. 19 writes ``psi_a = [1, gamma] / sqrt(gamma^2 + 1)`` with ``gamma = num / den``,
    ``num = 2(q0q3 + q1q2)``, ``den = q0^2 + q1^2 - q2^2 - q3^2``. Multiplying through by ``|den|`` gives
    ``[den, num] / sqrt(num^2 + den^2)``, identical where ``den > 0`` and, unlike the printed form, also
    right for ``|psi| > 90 deg`` (the printed ``cos`` is never negative). That is the form used here; it is
    continuous for every yaw, which is the point of eq. 18.
    """
    q0, q1, q2, q3 = q
    num = 2.0 * (q0 * q3 + q1 * q2)
    den = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    r2 = num * num + den * den
    if r2 < 1e-12:
        raise EkfError("yaw is undefined at 90 deg pitch (gimbal lock)")
    r = math.sqrt(r2)
    # d num / dq = 2 [q3, q2, q1, q0];  d den / dq = 2 [q0, q1, -q2, -q3]
    # d(den/r) = num (num d den - den d num) / r^3 ;  d(num/r) = den (den d num - num d den) / r^3
    k = 2.0 / (r2 * r)
    c0 = k * (den * q3 - num * q0)
    c1 = k * (den * q2 - num * q1)
    c2 = k * (den * q1 + num * q2)
    c3 = k * (den * q0 + num * q3)
    H = (
        (-num * c0, -num * c1, -num * c2, -num * c3),
        (den * c0, den * c1, den * c2, den * c3),
    )
    return (den / r, num / r), H


def rangefinder_model(
    q: tuple[float, float, float, float], pz_m: float
) -> tuple[float, tuple[float, float, float, float, float]]:
    """Range along the body's -z axis to the ground, ``s = pz / (q0^2 - q1^2 - q2^2 + q3^2)``, and its
    1x5 Jacobian: paper C eq. 21 (from eq. 20)."""
    q0, q1, q2, q3 = q
    cos_tilt = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    if cos_tilt < 0.1:
        raise EkfError(f"rangefinder model undefined for a tilt beyond 84 deg (R33 = {cos_tilt:.3f})")
    inv = 1.0 / cos_tilt
    k = -2.0 * pz_m * inv * inv
    return pz_m * inv, (k * q0, -k * q1, -k * q2, k * q3, inv)


def error_angle_covariance_world(q_world_body: npt.ArrayLike, covariance_q: npt.ArrayLike) -> FloatArray:
    """3x3 covariance of world-frame error angles ``dtheta`` (``q_true = [1, dtheta/2] * q``) from the 4x4
    covariance of a unit quaternion: ``dtheta = 2 Psi(q)^T dq``, ``Psi`` the left-product matrix."""
    q0, q1, q2, q3 = (float(v) for v in np.asarray(q_world_body, dtype=np.float64).reshape(4))
    Psi = np.array([[-q1, -q2, -q3], [q0, q3, -q2], [-q3, q0, q1], [q2, -q1, q0]])
    C = 4.0 * Psi.T @ np.asarray(covariance_q, dtype=np.float64).reshape(4, 4) @ Psi
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)


# --------------------------------------------------------------------------------------------------
# Chi-square gate thresholds (no scipy): inverse CDF by bisection of the closed forms for 1..3 dof.
# --------------------------------------------------------------------------------------------------


def chi_square_cdf(x: float, dof: int) -> float:
    """CDF of the chi-square distribution for 1, 2 or 3 degrees of freedom."""
    if x <= 0.0:
        return 0.0
    if dof == 1:
        return math.erf(math.sqrt(x / 2.0))
    if dof == 2:
        return 1.0 - math.exp(-x / 2.0)
    if dof == 3:
        return math.erf(math.sqrt(x / 2.0)) - math.sqrt(2.0 * x / math.pi) * math.exp(-x / 2.0)
    raise InputError(f"chi_square_cdf supports 1..3 degrees of freedom, got {dof}")


def chi_square_quantile(probability: float, dof: int) -> float:
    """Inverse of :func:`chi_square_cdf` (bisection, 1e-9 relative)."""
    lo, hi = 0.0, 1.0
    while chi_square_cdf(hi, dof) < probability:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi_square_cdf(mid, dof) < probability:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9 * hi:
            break
    return 0.5 * (lo + hi)


# --------------------------------------------------------------------------------------------------
# The filter.
# --------------------------------------------------------------------------------------------------


def _three_floats(v: npt.ArrayLike) -> tuple[float, float, float]:
    """A 3-vector as Python floats (fast path for float64 arrays of shape (3,))."""
    arr = v if isinstance(v, np.ndarray) and v.shape == (3,) else np.asarray(v, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"expected a 3-vector, got shape {arr.shape}")
    x, y, z = arr.tolist()
    return float(x), float(y), float(z)


def _normalized(q0: float, q1: float, q2: float, q3: float) -> tuple[tuple[float, float, float, float], bool]:
    """Unit quaternion with q0 >= 0, and whether the sign was flipped."""
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if not (n > 1e-9 and math.isfinite(n)):
        raise EkfError(f"quaternion norm degenerated to {n}")
    inv = 1.0 / n
    if q0 < 0.0:
        return (-q0 * inv, -q1 * inv, -q2 * inv, -q3 * inv), True
    return (q0 * inv, q1 * inv, q2 * inv, q3 * inv), False


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
        q = check_quaternion(q_world_body, "q_world_body")
        if q.shape != (4,):
            raise InputError(f"q_world_body must have shape (4,), got {q.shape}")
        if not (math.isfinite(pz_m) and math.isfinite(stamp_s)):
            raise InputError("pz_m and stamp_s must be finite")
        qn, _ = _normalized(*(float(v) for v in q))
        s = self.settings
        P = np.zeros((5, 5))
        # attitude angle std theta gives quaternion std theta/2 in the three directions orthogonal to q
        qa = np.asarray(qn)
        P[:4, :4] = (0.5 * s.initial_attitude_std_rad) ** 2 * (np.eye(4) - np.outer(qa, qa))
        P[4, 4] = s.initial_altitude_std_m**2
        return EkfState(q_world_body=qa, pz_m=float(pz_m), covariance=P, stamp_s=float(stamp_s))

    # ---- predict ----------------------------------------------------------------------------------

    def predict(self, state: EkfState, gyro_rad_s: npt.ArrayLike, dt_s: float) -> EkfState:
        """Gyro prediction over ``dt_s`` (paper C eqs. 1-3 with the models of eqs. 12-15).

        ``Q`` maps the gyro noise through the kinematics, ``Q_q = (dt/2)^2 sigma^2 Xi(q) Xi(q)^T =
        (dt/2)^2 sigma^2 (I - q q^T)``, plus the attitude and altitude random walks.
        """
        if not (dt_s >= 0.0 and math.isfinite(dt_s)):
            raise InputError(f"dt_s must be finite and >= 0, got {dt_s}")
        wx, wy, wz = _three_floats(gyro_rad_s)
        a, b, c = _transition_floats(wx, wy, wz, dt_s)
        q_prev = state.q_world_body.tolist()
        q0, q1, q2, q3 = propagate_quaternion((q_prev[0], q_prev[1], q_prev[2], q_prev[3]), a, b, c)
        F = _transition_matrix(a, b, c)
        qk = 0.25 * (dt_s * dt_s * self._gyro_var + dt_s * self._attitude_rw_var)
        qn, flipped = _normalized(q0, q1, q2, q3)
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
        ax, ay, az = _three_floats(accel_m_s2)
        s = self.settings
        mx, my, mz = motion_accel_world_m_s2
        f_world = (mx, my, mz + s.gravity_m_s2)
        norm = math.sqrt(ax * ax + ay * ay + az * az)
        if not math.isfinite(norm):
            raise InputError(f"accel_m_s2 must be finite, got {(ax, ay, az)}")
        expected = math.sqrt(f_world[0] ** 2 + f_world[1] ** 2 + f_world[2] ** 2)
        if abs(norm - expected) > s.accel_norm_tolerance_m_s2:
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
        qn, flipped = _normalized(q[0] + dx[0], q[1] + dx[1], q[2] + dx[2], q[3] + dx[3])
        if flipped:
            P_new *= self._sign_flip
        new = EkfState(
            q_world_body=np.array(qn), pz_m=state.pz_m + dx[4], covariance=P_new, stamp_s=state.stamp_s
        )
        return UpdateResult(state=new, accepted=True, nis=nis)
