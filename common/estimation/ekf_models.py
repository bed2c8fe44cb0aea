"""Paper C's EKF equations, one function each (section III-B, eqs. 12-21), the float helpers of the filters'
hot paths and the 5-state filter's steps (predict, accelerometer update, Kalman correction) as functions of
arrays. Shared by paper C's 5-state EKF (:mod:`common.estimation.ekf`) and the error-state filter with bias
states (:mod:`common.estimation.eskf`). The chi-square gates are in :mod:`common.estimation.chi_square`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from common.errors import CapatazError, InputError
from common.geometry import check_quaternion
from common.types import FloatArray

#: Standard gravity used by the accelerometer model (m/s^2).
STANDARD_GRAVITY_M_S2 = 9.80665


class EkfError(CapatazError):
    """The filter cannot continue (non-finite state or a singular innovation covariance)."""


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
    wx, wy, wz = three_floats(np.asarray(gyro_rad_s, dtype=np.float64))
    return transition_matrix(*transition_floats(wx, wy, wz, dt_s))


def transition_matrix(a: float, b: float, c: float) -> FloatArray:
    """``F`` of :func:`state_transition` from ``a, b, c = dt/2 * (wx, wy, wz)`` (the hot path's form)."""
    return np.array(
        [
            1.0, -a, -b, -c, 0.0,
            a, 1.0, c, -b, 0.0,
            b, -c, 1.0, a, 0.0,
            c, b, -a, 1.0, 0.0,
            0.0, 0.0, 0.0, 0.0, 1.0,
        ]
    ).reshape(5, 5)  # fmt: skip


def transition_floats(wx: float, wy: float, wz: float, dt_s: float) -> tuple[float, float, float]:
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


def altitude_from_range(q: tuple[float, float, float, float], range_m: float) -> float:
    """Altitude from a range reading along the body's -z axis: paper C eq. 21 inverted,
    ``pz = s (q0^2 - q1^2 - q2^2 + q3^2)`` (the inverse of :func:`rangefinder_model`)."""
    q0, q1, q2, q3 = q
    return float(range_m) * (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3)


def error_angle_covariance_world(q_world_body: npt.ArrayLike, covariance_q: npt.ArrayLike) -> FloatArray:
    """3x3 covariance of world-frame error angles ``dtheta`` (``q_true = [1, dtheta/2] * q``) from the 4x4
    covariance of a unit quaternion: ``dtheta = 2 Psi(q)^T dq``, ``Psi`` the left-product matrix."""
    q0, q1, q2, q3 = (float(v) for v in np.asarray(q_world_body, dtype=np.float64).reshape(4))
    Psi = np.array([[-q1, -q2, -q3], [q0, q3, -q2], [-q3, q0, q1], [q2, -q1, q0]])
    C = 4.0 * Psi.T @ np.asarray(covariance_q, dtype=np.float64).reshape(4, 4) @ Psi
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)


# --------------------------------------------------------------------------------------------------
# The filter.
# --------------------------------------------------------------------------------------------------


def three_floats(v: npt.ArrayLike) -> tuple[float, float, float]:
    """A 3-vector as Python floats (fast path for float64 arrays of shape (3,))."""
    arr = v if isinstance(v, np.ndarray) and v.shape == (3,) else np.asarray(v, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"expected a 3-vector, got shape {arr.shape}")
    x, y, z = arr.tolist()
    return float(x), float(y), float(z)


def normalized_quaternion(
    q0: float, q1: float, q2: float, q3: float
) -> tuple[tuple[float, float, float, float], bool]:
    """Unit quaternion with q0 >= 0, and whether the sign was flipped."""
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if not (n > 1e-9 and math.isfinite(n)):
        raise EkfError(f"quaternion norm degenerated to {n}")
    inv = 1.0 / n
    if q0 < 0.0:
        return (-q0 * inv, -q1 * inv, -q2 * inv, -q3 * inv), True
    return (q0 * inv, q1 * inv, q2 * inv, q3 * inv), False


def check_initial(
    q_world_body: npt.ArrayLike, pz_m: float, stamp_s: float
) -> tuple[tuple[float, float, float, float], float, float]:
    """A filter's starting point checked: the unit quaternion ``q_world_body`` (q0 >= 0), altitude and stamp
    as floats; a malformed quaternion or a non-finite altitude or stamp raises :class:`InputError`."""
    q = check_quaternion(q_world_body, "q_world_body")
    if q.shape != (4,):
        raise InputError(f"q_world_body must have shape (4,), got {q.shape}")
    if not (math.isfinite(pz_m) and math.isfinite(stamp_s)):
        raise InputError("pz_m and stamp_s must be finite")
    qn, _ = normalized_quaternion(*(float(v) for v in q))
    return qn, float(pz_m), float(stamp_s)


def expected_specific_force(
    measured_m_s2: tuple[float, float, float],
    motion_accel_world_m_s2: tuple[float, float, float],
    gravity_m_s2: float,
    tolerance_m_s2: float,
) -> tuple[float, float, float] | None:
    """The specific force the accelerometer should read, in the world (``a + g e_z``), or None when the
    measured one's norm is further than ``tolerance_m_s2`` from it (the vehicle accelerates beyond the model:
    the update is skipped). A non-finite measurement raises :class:`InputError`."""
    mx, my, mz = motion_accel_world_m_s2
    f_world = (mx, my, mz + gravity_m_s2)
    norm = math.sqrt(sum(v * v for v in measured_m_s2))
    if not math.isfinite(norm):
        raise InputError(f"accel_m_s2 must be finite, got {measured_m_s2}")
    expected = math.sqrt(f_world[0] ** 2 + f_world[1] ** 2 + f_world[2] ** 2)
    return None if abs(norm - expected) > tolerance_m_s2 else f_world


def with_reset_block(covariance: FloatArray, index: int | slice, variance: float) -> FloatArray:
    """A copy of ``covariance`` with the states at ``index`` uncorrelated from the rest and ``variance``
    on their diagonal (a state replaced by a fresh measurement)."""
    P = np.array(covariance, dtype=np.float64)
    P[index, :] = 0.0
    P[:, index] = 0.0
    rows = np.arange(P.shape[0])[index]
    P[rows, rows] = variance
    return P


# --------------------------------------------------------------------------------------------------
# Paper C's 5-state filter's steps (:class:`~common.estimation.ekf.AttitudeAltitudeEkf`): arrays in and out,
# so that a filter step calls this module once.
# --------------------------------------------------------------------------------------------------

Quaternion = tuple[float, float, float, float]
#: After a sign flip of the quaternion, its covariance with the altitude changes sign.
_SIGN_FLIP = np.ones((5, 5))
_SIGN_FLIP[4, :4] = -1.0
_SIGN_FLIP[:4, 4] = -1.0
_SIGN_FLIP.setflags(write=False)
#: A correction: the new quaternion, altitude and covariance (None when the gate refused the measurement).
Corrected = tuple[Quaternion, float, FloatArray] | None


def predict_step(
    q_world_body: FloatArray,
    covariance: FloatArray,
    gyro_rad_s: npt.ArrayLike,
    dt_s: float,
    gyro_var: float,
    attitude_rw_var: float,
    altitude_rw_var: float,
) -> tuple[Quaternion, FloatArray]:
    """Gyro prediction over ``dt_s`` (paper C eqs. 1-3 with the models of eqs. 12-15): the unit quaternion and
    the covariance (:meth:`~common.estimation.ekf.AttitudeAltitudeEkf.predict` documents it)."""
    wx, wy, wz = three_floats(gyro_rad_s)
    a, b, c = transition_floats(wx, wy, wz, dt_s)
    q_prev = q_world_body.tolist()
    q0, q1, q2, q3 = propagate_quaternion((q_prev[0], q_prev[1], q_prev[2], q_prev[3]), a, b, c)
    F = transition_matrix(a, b, c)
    qk = 0.25 * (dt_s * dt_s * gyro_var + dt_s * attitude_rw_var)
    qn, flipped = normalized_quaternion(q0, q1, q2, q3)
    n0, n1, n2, n3 = qn
    m0, m1, m2, m3 = -qk * n0, -qk * n1, -qk * n2, -qk * n3
    Q = np.array(
        [
            qk + m0 * n0, m0 * n1, m0 * n2, m0 * n3, 0.0,
            m1 * n0, qk + m1 * n1, m1 * n2, m1 * n3, 0.0,
            m2 * n0, m2 * n1, qk + m2 * n2, m2 * n3, 0.0,
            m3 * n0, m3 * n1, m3 * n2, qk + m3 * n3, 0.0,
            0.0, 0.0, 0.0, 0.0, dt_s * altitude_rw_var,
        ]
    ).reshape(5, 5)  # fmt: skip
    P = np.dot(np.dot(F, covariance), F.T) + Q
    if flipped:
        P *= _SIGN_FLIP
    return qn, P


def accelerometer_step(
    q_world_body: FloatArray,
    pz_m: float,
    covariance: FloatArray,
    accel_m_s2: npt.ArrayLike,
    motion_accel_world_m_s2: tuple[float, float, float],
    gravity_m_s2: float,
    tolerance_m_s2: float,
    variance: float,
    gate: float,
) -> tuple[float, Corrected]:
    """Accelerometer update with the model of eq. 16 (eqs. 4-8): its NIS and the correction (NIS nan and no
    correction when skipped by :func:`expected_specific_force`)."""
    ax, ay, az = three_floats(accel_m_s2)
    f_world = expected_specific_force((ax, ay, az), motion_accel_world_m_s2, gravity_m_s2, tolerance_m_s2)
    if f_world is None:
        return math.nan, None
    q = q_world_body.tolist()
    h, Hq = accelerometer_model((q[0], q[1], q[2], q[3]), f_world)
    (h00, h01, h02, h03), (h10, h11, h12, h13), (h20, h21, h22, h23) = Hq
    H = np.array([h00, h01, h02, h03, 0.0, h10, h11, h12, h13, 0.0, h20, h21, h22, h23, 0.0]).reshape(3, 5)
    return correct_step(q_world_body, pz_m, covariance, (ax - h[0], ay - h[1], az - h[2]), H, variance, gate)


def correct_step(
    q_world_body: FloatArray,
    pz_m: float,
    covariance: FloatArray,
    innovation: tuple[float, ...],
    H: FloatArray,
    variance: float,
    gate: float,
) -> tuple[float, Corrected]:
    """Kalman gain, gate and correction, paper C eqs. 6-8, with closed-form inverses of S (m <= 3): the NIS
    and the correction (None when the NIS is beyond ``gate``)."""
    P = covariance
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
        Sy = [c00 * y0 + c01 * y1 + c02 * y2, c01 * y0 + c11 * y1 + c12 * y2, c02 * y0 + c12 * y1 + c22 * y2]
        nis = y0 * Sy[0] + y1 * Sy[1] + y2 * Sy[2]
    if not math.isfinite(nis):
        raise InputError("innovation is not finite")
    if nis > gate:
        return nis, None
    K = np.dot(PHt, np.array(Sinv))  # (5, m), eq. 6
    dx = np.dot(PHt, np.array(Sy)).tolist()  # K y, eq. 7
    P_new = P - np.dot(K, PHt.T)  # eq. 8, (I - K H) P
    q = q_world_body.tolist()
    qn, flipped = normalized_quaternion(q[0] + dx[0], q[1] + dx[1], q[2] + dx[2], q[3] + dx[3])
    if flipped:
        P_new *= _SIGN_FLIP
    return nis, (qn, pz_m + dx[4], P_new)
