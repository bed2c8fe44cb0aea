"""The bias filter in plain NumPy, one equation a line: the reference the compiled filter
(:mod:`common.estimation.eskf`, :mod:`common.estimation.eskf_kernels`) is held to in
``test_eskf_kernels.py``. Same models, same layout, dense matrices, no shortcuts."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.estimation.chi_square import chi_square_quantile
from common.estimation.ekf_models import (
    accelerometer_model,
    normalized_quaternion,
    propagate_quaternion,
    three_floats,
)
from common.estimation.eskf_math import (
    checked_position,
    error_jacobian,
    inverse_spd,
    range_observation,
    yaw_observation,
)
from common.estimation.eskf_state import BiasEkfSettings
from common.types import FloatArray

#: Error-state layout.
THETA, PZ, BG, BA, PXY, VXY, VZ = slice(0, 3), 3, slice(4, 7), slice(7, 10), slice(10, 12), slice(12, 14), 14
N_ERROR = 15

__all__ = ["BiasEkfSettings", "ReferenceEskf", "ReferenceResult", "ReferenceState", "error_jacobian"]

#: kept for the tests that import it from here
_inverse_spd = inverse_spd


@dataclass(frozen=True)
class ReferenceState:
    """Nominal state at ``stamp_s`` and the 15x15 error-state covariance (layout :data:`THETA` ...)."""

    q_world_body: FloatArray
    pz_m: float
    gyro_bias_rad_s: FloatArray
    accel_bias_m_s2: FloatArray
    covariance: FloatArray
    stamp_s: float
    p_xy_m: FloatArray = field(default_factory=lambda: np.zeros(2))
    v_xy_m_s: FloatArray = field(default_factory=lambda: np.zeros(2))
    vz_m_s: float = 0.0


@dataclass(frozen=True)
class ReferenceResult:
    """Outcome of one update: the new state, whether the gate accepted it, and its NIS."""

    state: ReferenceState
    accepted: bool
    nis: float


def rotation_rows(
    q: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """``R_world_body`` of a unit quaternion, row-major, as floats."""
    q0, q1, q2, q3 = q
    return (
        1.0 - 2.0 * (q2 * q2 + q3 * q3), 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
        2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q1 * q1 + q3 * q3), 2.0 * (q2 * q3 - q0 * q1),
        2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2),
    )  # fmt: skip


def inject_attitude(
    q: tuple[float, float, float, float], dx: float, dy: float, dz: float
) -> tuple[float, float, float, float]:
    """``q * [1, dtheta/2]`` normalised (right product: body-frame error)."""
    q0, q1, q2, q3 = q
    a, b, c = 0.5 * dx, 0.5 * dy, 0.5 * dz
    qn, _ = normalized_quaternion(
        q0 - q1 * a - q2 * b - q3 * c,
        q1 + q0 * a + q2 * c - q3 * b,
        q2 + q0 * b + q3 * a - q1 * c,
        q3 + q0 * c + q1 * b - q2 * a,
    )
    return qn


class ReferenceEskf:
    """The error-state filter in NumPy (state in, state out)."""

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

    def predict(
        self,
        state: ReferenceState,
        gyro_rad_s: npt.ArrayLike,
        dt_s: float,
        accel_m_s2: npt.ArrayLike | None = None,
    ) -> ReferenceState:
        """Bias-corrected gyro over ``dt_s``: nominal by eq. 12, covariance ``F P F^T + Q`` with
        ``F_theta_theta = I - [w dt]x``, ``F_theta_bg = -I dt``. With ``accel_m_s2`` the horizontal velocity
        and position integrate ``a = R (f - b_a)``, ``R`` at the interval's middle attitude
        (``F_v_theta = -(R [f - b_a]x) dt``, ``F_v_ba = -R dt``, ``F_p_v = I dt``); without it they keep a
        constant velocity."""
        if not (dt_s >= 0.0 and math.isfinite(dt_s)):
            raise InputError(f"dt_s must be finite and >= 0, got {dt_s}")
        gx, gy, gz = three_floats(gyro_rad_s)
        bx, by, bz = state.gyro_bias_rad_s.tolist()
        wx, wy, wz = gx - bx, gy - by, gz - bz
        half = 0.5 * dt_s
        q = state.q_world_body.tolist()
        qt = (q[0], q[1], q[2], q[3])
        q0, q1, q2, q3 = propagate_quaternion(qt, half * wx, half * wy, half * wz)
        qn, _ = normalized_quaternion(q0, q1, q2, q3)
        F = self._F
        ax, ay, az = wx * dt_s, wy * dt_s, wz * dt_s
        F[0, 1], F[0, 2], F[1, 0], F[1, 2], F[2, 0], F[2, 1] = az, -ay, -az, ax, ay, -ax
        F[0, 4] = F[1, 5] = F[2, 6] = -dt_s
        F[10, 12] = F[11, 13] = F[3, 14] = dt_s
        vx, vy = state.v_xy_m_s.tolist()
        vz = state.vz_m_s
        px, py = state.p_xy_m.tolist()
        if accel_m_s2 is None:
            F[12:15, 0:3] = 0.0
            F[12:15, 7:10] = 0.0
            nx, ny, nz = vx, vy, vz
        else:
            fx, fy, fz = three_floats(accel_m_s2)
            cbx, cby, cbz = state.accel_bias_m_s2.tolist()
            fx, fy, fz = fx - cbx, fy - cby, fz - cbz
            # R at the interval's middle attitude: the old and the propagated quaternion's mean
            norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
            mid = np.array(qt) + np.array((q0, q1, q2, q3)) / norm
            m0, m1, m2, m3 = (mid / np.linalg.norm(mid)).tolist()
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = rotation_rows((m0, m1, m2, m3))
            a_x = r00 * fx + r01 * fy + r02 * fz
            a_y = r10 * fx + r11 * fy + r12 * fz
            a_z = r20 * fx + r21 * fy + r22 * fz - self.settings.gravity_m_s2
            # -(R [f]x) dt, rows x and y; [f]x = [[0, -fz, fy], [fz, 0, -fx], [-fy, fx, 0]]
            F[12, 0] = -(r01 * fz - r02 * fy) * dt_s
            F[12, 1] = -(r02 * fx - r00 * fz) * dt_s
            F[12, 2] = -(r00 * fy - r01 * fx) * dt_s
            F[13, 0] = -(r11 * fz - r12 * fy) * dt_s
            F[13, 1] = -(r12 * fx - r10 * fz) * dt_s
            F[13, 2] = -(r10 * fy - r11 * fx) * dt_s
            F[12, 7], F[12, 8], F[12, 9] = -r00 * dt_s, -r01 * dt_s, -r02 * dt_s
            F[13, 7], F[13, 8], F[13, 9] = -r10 * dt_s, -r11 * dt_s, -r12 * dt_s
            F[14, 0] = -(r21 * fz - r22 * fy) * dt_s
            F[14, 1] = -(r22 * fx - r20 * fz) * dt_s
            F[14, 2] = -(r20 * fy - r21 * fx) * dt_s
            F[14, 7], F[14, 8], F[14, 9] = -r20 * dt_s, -r21 * dt_s, -r22 * dt_s
            nx, ny, nz = vx + a_x * dt_s, vy + a_y * dt_s, vz + a_z * dt_s
        F = F.copy()
        P = F @ state.covariance @ F.T
        P += self._process_noise(dt_s)
        return ReferenceState(
            np.array(qn),
            state.pz_m + half * (vz + nz),
            state.gyro_bias_rad_s,
            state.accel_bias_m_s2,
            P,
            state.stamp_s + dt_s,
            np.array((px + half * (vx + nx), py + half * (vy + ny))),
            np.array((nx, ny)),
            nz,
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
            np.zeros(2),
            np.full(3, dt_s * s.velocity_random_walk_m_s_sqrt_s**2),
        ]
        self._Q = np.diag(diag)
        self._q_dt_s = dt_s
        return self._Q

    # ---- updates --------------------------------------------------------------------------------------

    def update_accelerometer(
        self,
        state: ReferenceState,
        accel_m_s2: npt.ArrayLike,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> ReferenceResult:
        """Accelerometer: eq. 16 plus the bias, ``h = R^T (a + g e_z) + b_a``; skipped like the 5-state
        filter's when the bias-corrected specific force is far from the expected norm."""
        ax, ay, az = three_floats(accel_m_s2)
        bax, bay, baz = state.accel_bias_m_s2.tolist()
        cx, cy, cz = ax - bax, ay - bay, az - baz
        s = self.settings
        mx, my, mz = motion_accel_world_m_s2
        f_world = (mx, my, mz + s.gravity_m_s2)
        norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        if not math.isfinite(norm):
            raise InputError(f"accel_m_s2 must be finite, got {(ax, ay, az)}")
        expected = math.sqrt(f_world[0] ** 2 + f_world[1] ** 2 + f_world[2] ** 2)
        if abs(norm - expected) > s.accel_norm_tolerance_m_s2:
            return ReferenceResult(state, False, math.nan)
        q = state.q_world_body.tolist()
        h, _ = accelerometer_model((q[0], q[1], q[2], q[3]), f_world)
        # dh/dtheta of R^T f for q * [1, dtheta/2] is [h]x (the cross-product matrix of eq. 16's h;
        # the tests check it against the quaternion Jacobian times dq/dtheta); dh/db_a = I
        hx, hy, hz = h
        Ht = np.array([[0.0, hz, -hy], [-hz, 0.0, hx], [hy, -hx, 0.0]])  # ([h]x)^T
        P = state.covariance
        PHt = P[:, THETA] @ Ht + P[:, BA]  # (15, 3)
        S = Ht.T @ PHt[THETA] + PHt[BA] + self._accel_R
        extra = s.motion_accel_noise_share**2 * (mx * mx + my * my + mz * mz)
        if extra > 0.0:
            S = S + np.eye(3) * extra
        return self._correct(state, PHt, S, (cx - hx, cy - hy, cz - hz))

    def update_position(
        self, state: ReferenceState, p_xy_m: npt.ArrayLike, noise_m: float | None = None
    ) -> ReferenceResult:
        """Horizontal position ``p_xy_m`` (navigation frame, e.g. the visual odometry's), std ``noise_m``
        (default ``settings.position_noise_m``)."""
        std = self.settings.position_noise_m if noise_m is None else float(noise_m)
        p = checked_position(p_xy_m, std)
        P = state.covariance
        PHt = P[:, PXY]
        S = PHt[PXY] + np.eye(2) * std**2
        px, py = state.p_xy_m.tolist()
        mx, my = p.tolist()
        return self._correct(state, PHt, S, (mx - px, my - py))

    def update_yaw(
        self, state: ReferenceState, yaw_rad: float, yaw_noise_rad: float | None = None
    ) -> ReferenceResult:
        """Yaw: the filter's innovation and Jacobian (not compiled), the reference's correction."""
        y, H = yaw_observation(state.q_world_body, yaw_rad)
        var = self._yaw_var if yaw_noise_rad is None else float(yaw_noise_rad) ** 2
        return self._update(state, y, H, np.eye(2) * var)

    def update_range(self, state: ReferenceState, range_m: float) -> ReferenceResult:
        """Rangefinder: the filter's innovation and Jacobian (not compiled), the reference's correction."""
        y, H = range_observation(state.q_world_body, state.pz_m, range_m)
        return self._update(state, y, H, np.array([[self._range_var]]))

    def _update(self, state: ReferenceState, y: FloatArray, H: FloatArray, R: FloatArray) -> ReferenceResult:
        """Update with a dense ``H`` (range, yaw)."""
        PHt = state.covariance @ H.T
        return self._correct(state, PHt, H @ PHt + R, tuple(float(v) for v in y))

    def _correct(
        self, state: ReferenceState, PHt: FloatArray, S: FloatArray, y: tuple[float, ...]
    ) -> ReferenceResult:
        """Gate, gain, ``(I - K H) P`` and injection of the error state (closed-form ``S^-1``, m <= 3)."""
        Sinv = inverse_spd(S)
        m = len(y)
        yv = np.array(y)
        Sy = Sinv @ yv
        nis = float(yv @ Sy)
        if not math.isfinite(nis):
            raise InputError("innovation is not finite")
        if nis > self._gate[m]:
            return ReferenceResult(state, False, nis)
        K = PHt @ Sinv
        dx = (PHt @ Sy).tolist()
        P_new = state.covariance - K @ PHt.T
        q = state.q_world_body.tolist()
        qn = inject_attitude((q[0], q[1], q[2], q[3]), dx[0], dx[1], dx[2])
        dxa = np.array(dx)
        new = ReferenceState(
            q_world_body=np.array(qn),
            pz_m=state.pz_m + dx[3],
            gyro_bias_rad_s=state.gyro_bias_rad_s + dxa[BG],
            accel_bias_m_s2=state.accel_bias_m_s2 + dxa[BA],
            covariance=P_new,
            stamp_s=state.stamp_s,
            p_xy_m=state.p_xy_m + dxa[PXY],
            v_xy_m_s=state.v_xy_m_s + dxa[VXY],
            vz_m_s=state.vz_m_s + dx[VZ],
        )
        return ReferenceResult(new, True, nis)
