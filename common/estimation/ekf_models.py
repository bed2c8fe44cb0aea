"""Paper C's EKF equations, one function each (section III-B, eqs. 12-21), the chi-square gate thresholds and
the float helpers of the filters' hot paths. Shared by paper C's 5-state EKF (:mod:`common.estimation.ekf`)
and the error-state filter with bias states (:mod:`common.estimation.eskf`).
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
