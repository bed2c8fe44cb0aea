"""Compiled (numba) steps of the error-state EKF (:mod:`common.estimation.eskf`): its hot path.

The filter runs at the IMU's 400 Hz; in NumPy a 15x15 predict and a 3-row update are some 40 small-array
calls of about a microsecond each. Here one call does the whole step on a fixed layout, without temporary
Python objects: the nominal state is one vector (:data:`NOMINAL` layout), the covariance is 15x15, and the
covariance predict skips the zeros of the sparse transition matrix and fills ``F P F^T`` symmetrically.
Paper C's equations come from their one home (:mod:`common.estimation.ekf_models`), compiled as they are.
``tests/common/estimation/eskf_reference.py`` is the plain NumPy version the tests compare against.

Status codes instead of exceptions (the wrappers in :mod:`common.estimation.eskf` raise them):
:data:`OK`, :data:`SKIPPED` (accelerometer norm check), :data:`GATED`, :data:`NOT_FINITE`,
:data:`NOT_POSITIVE` (innovation covariance), :data:`DEGENERATE` (quaternion norm).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from common.estimation import ekf_models
from common.types import FloatArray

#: Nominal state vector: q (0-3), pz (4), b_g (5-7), b_a (8-10), p_xy (11-12), v_xy (13-14), v_z (15).
Q0, PZ_X, BG_X, BA_X, PXY_X, VXY_X, VZ_X = 0, 4, 5, 8, 11, 13, 15
N_NOMINAL = 16
#: Error state: dtheta (0-2), dpz (3), db_g (4-6), db_a (7-9), dp_xy (10-11), dv_xy (12-13), dv_z (14).
N_ERR = 15

OK, SKIPPED, GATED, NOT_FINITE, NOT_POSITIVE, DEGENERATE = 0, 1, 2, 3, 4, 5

_propagate_quaternion = njit(cache=True)(ekf_models.propagate_quaternion)
_accelerometer_model = njit(cache=True)(ekf_models.accelerometer_model)


@njit(cache=True)
def _sandwich_plus_noise(
    F: FloatArray, P: FloatArray, dt: float, q_rate: FloatArray, q_rate2: FloatArray
) -> FloatArray:
    """``F P F^T + Q`` for a sparse ``F`` and symmetric ``P`` (upper triangle, mirrored); ``Q`` diagonal,
    ``dt q_rate + dt^2 q_rate2`` (random walks and white noise integrated over ``dt``)."""
    n = P.shape[0]
    FP = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            f = F[i, k]
            if f != 0.0:
                for j in range(n):
                    FP[i, j] += f * P[k, j]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                f = F[j, k]
                if f != 0.0:
                    s += FP[i, k] * f
            out[i, j] = s
            out[j, i] = s
        out[i, i] += dt * q_rate[i] + dt * dt * q_rate2[i]
    return out


@njit(cache=True)
def predict_step(
    x: FloatArray,
    P: FloatArray,
    gyro: FloatArray,
    accel: FloatArray,
    use_accel: bool,
    dt: float,
    q_rate: FloatArray,
    q_rate2: FloatArray,
    gravity: float,
) -> tuple[int, FloatArray, FloatArray]:
    """One predict (the documentation is :meth:`common.estimation.eskf.BiasAwareEkf.predict`'s)."""
    wx, wy, wz = gyro[0] - x[5], gyro[1] - x[6], gyro[2] - x[7]
    half = 0.5 * dt
    qo = (x[0], x[1], x[2], x[3])
    q0, q1, q2, q3 = _propagate_quaternion(qo, half * wx, half * wy, half * wz)
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if not (norm > 1e-9 and math.isfinite(norm)):
        return DEGENERATE, x, P
    inv = -1.0 / norm if q0 < 0.0 else 1.0 / norm
    xn = x.copy()
    xn[0], xn[1], xn[2], xn[3] = q0 * inv, q1 * inv, q2 * inv, q3 * inv
    F = np.eye(N_ERR)
    ax, ay, az = wx * dt, wy * dt, wz * dt
    F[0, 1], F[0, 2], F[1, 0], F[1, 2], F[2, 0], F[2, 1] = az, -ay, -az, ax, ay, -ax
    F[0, 4] = F[1, 5] = F[2, 6] = -dt
    F[10, 12] = F[11, 13] = F[3, 14] = dt
    vx, vy, vz = x[13], x[14], x[15]
    nx, ny, nz = vx, vy, vz
    if use_accel:
        fx, fy, fz = accel[0] - x[8], accel[1] - x[9], accel[2] - x[10]
        # the specific force turned into the world at the interval's middle attitude (the mean of the old
        # and the propagated quaternion, unflipped, so the two are on the same side): at the old one the
        # world acceleration lags by half the turn of the interval, an error of g * w * dt / 2 that reads as
        # a tilt error (0.06 m/s^2 at 100 Hz and 67 deg/s)
        m0, m1, m2, m3 = x[0] + q0 / norm, x[1] + q1 / norm, x[2] + q2 / norm, x[3] + q3 / norm
        mn = 1.0 / math.sqrt(m0 * m0 + m1 * m1 + m2 * m2 + m3 * m3)
        a0, a1, a2, a3 = m0 * mn, m1 * mn, m2 * mn, m3 * mn
        r00 = 1.0 - 2.0 * (a2 * a2 + a3 * a3)
        r01 = 2.0 * (a1 * a2 - a0 * a3)
        r02 = 2.0 * (a1 * a3 + a0 * a2)
        r10 = 2.0 * (a1 * a2 + a0 * a3)
        r11 = 1.0 - 2.0 * (a1 * a1 + a3 * a3)
        r12 = 2.0 * (a2 * a3 - a0 * a1)
        r20 = 2.0 * (a1 * a3 - a0 * a2)
        r21 = 2.0 * (a2 * a3 + a0 * a1)
        r22 = 1.0 - 2.0 * (a1 * a1 + a2 * a2)
        rows = ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22))
        for r in range(3):
            c0, c1, c2 = rows[r]
            # -(R [f]x) dt and -R dt
            F[12 + r, 0] = -(c1 * fz - c2 * fy) * dt
            F[12 + r, 1] = -(c2 * fx - c0 * fz) * dt
            F[12 + r, 2] = -(c0 * fy - c1 * fx) * dt
            F[12 + r, 7], F[12 + r, 8], F[12 + r, 9] = -c0 * dt, -c1 * dt, -c2 * dt
        nx = vx + (r00 * fx + r01 * fy + r02 * fz) * dt
        ny = vy + (r10 * fx + r11 * fy + r12 * fz) * dt
        nz = vz + (r20 * fx + r21 * fy + r22 * fz - gravity) * dt
    xn[4] = x[4] + half * (vz + nz)
    xn[11] = x[11] + half * (vx + nx)
    xn[12] = x[12] + half * (vy + ny)
    xn[13], xn[14], xn[15] = nx, ny, nz
    return OK, xn, _sandwich_plus_noise(F, P, dt, q_rate, q_rate2)


@njit(cache=True)
def _inverse_small(S: FloatArray) -> tuple[bool, FloatArray]:
    """Closed-form inverse of a symmetric positive-definite 1x1, 2x2 or 3x3 matrix (False if not PD)."""
    m = S.shape[0]
    out = np.empty((m, m))
    if m == 1:
        if not S[0, 0] > 0.0:
            return False, out
        out[0, 0] = 1.0 / S[0, 0]
        return True, out
    if m == 2:
        s01 = 0.5 * (S[0, 1] + S[1, 0])
        det = S[0, 0] * S[1, 1] - s01 * s01
        if not det > 0.0:
            return False, out
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = S[1, 1] / det, -s01 / det, -s01 / det, S[0, 0] / det
        return True, out
    s00, s01, s02, s11, s12, s22 = S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2]
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not det > 0.0:
        return False, out
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    out[0, 0], out[0, 1], out[0, 2] = c00 / det, c01 / det, c02 / det
    out[1, 0], out[1, 1], out[1, 2] = c01 / det, c11 / det, c12 / det
    out[2, 0], out[2, 1], out[2, 2] = c02 / det, c12 / det, c22 / det
    return True, out


def inverse_small(S: FloatArray) -> tuple[bool, FloatArray]:
    """:func:`_inverse_small` for Python callers (float64 copy of ``S``)."""
    ok, out = _inverse_small(np.ascontiguousarray(S, dtype=np.float64))
    return bool(ok), out


@njit(cache=True)
def correct_step(
    x: FloatArray, P: FloatArray, PHt: FloatArray, S: FloatArray, y: FloatArray, gate: float
) -> tuple[int, float, FloatArray, FloatArray]:
    """Gate, gain, ``P - K (P H^T)^T`` and the injection of the error state (``q * [1, dtheta/2]``)."""
    ok, Sinv = _inverse_small(S)
    if not ok:
        return NOT_POSITIVE, math.nan, x, P
    m = y.shape[0]
    n = P.shape[0]
    Sy = Sinv @ y
    nis = 0.0
    for i in range(m):
        nis += y[i] * Sy[i]
    if not math.isfinite(nis):
        return NOT_FINITE, nis, x, P
    if nis > gate:
        return GATED, nis, x, P
    K = PHt @ Sinv
    dx = PHt @ Sy
    Pn = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            s = P[i, j]
            for k in range(m):
                s -= K[i, k] * PHt[j, k]
            Pn[i, j] = s
            Pn[j, i] = s
    xn = x.copy()
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    a, b, c = 0.5 * dx[0], 0.5 * dx[1], 0.5 * dx[2]
    r0 = q0 - q1 * a - q2 * b - q3 * c
    r1 = q1 + q0 * a + q2 * c - q3 * b
    r2 = q2 + q0 * b + q3 * a - q1 * c
    r3 = q3 + q0 * c + q1 * b - q2 * a
    norm = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2 + r3 * r3)
    if not (norm > 1e-9 and math.isfinite(norm)):
        return DEGENERATE, nis, x, P
    inv = -1.0 / norm if r0 < 0.0 else 1.0 / norm
    xn[0], xn[1], xn[2], xn[3] = r0 * inv, r1 * inv, r2 * inv, r3 * inv
    for i in range(3, N_ERR):
        xn[i + 1] = x[i + 1] + dx[i]
    return OK, nis, xn, Pn


@njit(cache=True)
def accelerometer_step(
    x: FloatArray,
    P: FloatArray,
    accel: FloatArray,
    mx: float,
    my: float,
    mz: float,
    gravity: float,
    noise_var: float,
    motion_share: float,
    norm_tolerance: float,
    gate: float,
) -> tuple[int, float, FloatArray, FloatArray]:
    """One accelerometer update (the documentation is
    :meth:`common.estimation.eskf.BiasAwareEkf.update_accelerometer`'s)."""
    cx, cy, cz = accel[0] - x[8], accel[1] - x[9], accel[2] - x[10]
    norm = math.sqrt(cx * cx + cy * cy + cz * cz)
    if not math.isfinite(norm):
        return NOT_FINITE, math.nan, x, P
    f_world = (mx, my, mz + gravity)
    expected = math.sqrt(f_world[0] ** 2 + f_world[1] ** 2 + f_world[2] ** 2)
    if abs(norm - expected) > norm_tolerance:
        return SKIPPED, math.nan, x, P
    h, _ = _accelerometer_model((x[0], x[1], x[2], x[3]), f_world)
    hx, hy, hz = h
    # dh/dtheta = [h]x, dh/db_a = I: P H^T = P[:, theta] [h]x^T + P[:, b_a]
    n = P.shape[0]
    PHt = np.empty((n, 3))
    for i in range(n):
        p0, p1, p2 = P[i, 0], P[i, 1], P[i, 2]
        PHt[i, 0] = -hz * p1 + hy * p2 + P[i, 7]
        PHt[i, 1] = hz * p0 - hx * p2 + P[i, 8]
        PHt[i, 2] = -hy * p0 + hx * p1 + P[i, 9]
    S = np.empty((3, 3))
    extra = noise_var + motion_share * motion_share * (mx * mx + my * my + mz * mz)
    for j in range(3):
        # row j of H applied to column j of P H^T
        S[0, j] = -hz * PHt[1, j] + hy * PHt[2, j] + PHt[7, j]
        S[1, j] = hz * PHt[0, j] - hx * PHt[2, j] + PHt[8, j]
        S[2, j] = -hy * PHt[0, j] + hx * PHt[1, j] + PHt[9, j]
    for j in range(3):
        S[j, j] += extra
    y = np.array((cx - hx, cy - hy, cz - hz))
    return correct_step(x, P, PHt, S, y, gate)
