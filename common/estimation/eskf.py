"""Error-state EKF with gyro and accelerometer bias states: paper C's observation models, EKF2-style state.

The state, its settings and an update's result are in :mod:`common.estimation.eskf_state`: the nominal
state ``q_world_body``, altitude, gyro and accelerometer biases, horizontal position and velocity; the error
state (15) with the body-frame attitude error ``dtheta`` (``q_true = q * [1, dtheta/2]``).

- Predict: the bias-corrected gyro through paper C's quaternion kinematics (eq. 12,
  :func:`~common.estimation.ekf.propagate_quaternion`); the error dynamics ``dtheta' = -[w]x dtheta - db_g``,
  constant altitude and bias random walks.
- Predict with the accelerometer too: velocity and position (altitude included) integrate the bias-corrected
  specific force rotated to the navigation frame, minus gravity (strapdown inertial navigation, as PX4's
  EKF2 and ArduPilot's EKF3); ``dv' = -(R [f]x) dtheta - R db_a``. Paper C's constant-altitude model
  locks the rangefinder out when the vehicle climbs faster than its random walk allows.
- Position update (:meth:`BiasAwareEkf.update_position`) with the visual odometry's horizontal position:
  aided this way, a tilt error shows as a growing velocity and position error, so the tilt stays observable
  during manoeuvres, when the accelerometer alone is no tilt reference.
- Updates: the accelerometer (eq. 16) plus ``b_a``, with its noise raised by the uncertainty of the
  manoeuvre acceleration it is compensated for, the yaw ``[cos psi, sin psi]`` (eq. 19) and the
  rangefinder (eq. 21), each from the paper-C model function of :mod:`common.estimation.ekf`; their
  quaternion Jacobians become error-state Jacobians through ``dq/dtheta = 1/2 Xi(q)``. The same chi-square
  gates and accelerometer norm check as :class:`~common.estimation.ekf.AttitudeAltitudeEkf`.

The steps run compiled (:mod:`common.estimation.eskf_kernels`): one call per predict or update, the
nominal state one vector; the tests hold them to a plain NumPy reference.

Why: a constant accelerometer bias ``b`` reads as a tilt of ``b/g`` to paper C's 5-state filter (0.05 m/s^2
is 0.3 deg), and that tilt error feeds the rectification. A body-fixed bias and a world-fixed tilt error
separate as soon as the vehicle yaws, which is what these states let the filter use.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from common.bounds import check_duration
from common.errors import InputError
from common.estimation import eskf_kernels as kernels
from common.estimation.chi_square import chi_square_quantile
from common.estimation.ekf import ImuStepResult
from common.estimation.ekf_models import (
    EkfError,
    check_initial,
    with_reset_block,
)
from common.estimation.eskf_math import (
    attitude_covariance_world,
    checked_position,
    compile_kernels,
    error_jacobian,
    range_observation,
    yaw_observation,
)
from common.estimation.eskf_state import (
    BA,
    N_ERROR,
    PXY,
    PZ,
    BiasEkfSettings,
    BiasEkfState,
    BiasUpdateResult,
    error_variances,
)
from common.geometry import matrix_from_quaternion
from common.types import FloatArray

__all__ = ["BiasAwareEkf", "error_jacobian"]

_ZERO3 = np.zeros(3)


def _vector3(v: npt.ArrayLike, name: str) -> FloatArray:
    """A float64 3-vector (no copy when it already is one)."""
    if isinstance(v, np.ndarray) and v.shape == (3,) and v.dtype == np.float64:
        return v
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape != (3,):
        raise InputError(f"{name} must be a 3-vector, got shape {arr.shape}")
    return arr


def _raise_for(status: int, what: str) -> None:
    if status == kernels.NOT_FINITE:
        raise InputError(f"{what}: the innovation is not finite")
    if status == kernels.NOT_POSITIVE:
        raise EkfError(f"{what}: the innovation covariance is not positive definite")
    if status == kernels.DEGENERATE:
        raise EkfError(f"{what}: the quaternion norm degenerated")


class BiasAwareEkf:
    """The error-state filter. Immutable: every method takes a :class:`BiasEkfState` and returns a new one."""

    def __init__(self, settings: BiasEkfSettings | None = None) -> None:
        self.settings = settings or BiasEkfSettings()
        s = self.settings
        self._gate = {dof: chi_square_quantile(s.gate_probability, dof) for dof in (1, 2, 3)}
        self._accel_var = s.accel_noise_m_s2**2
        self._range_var = s.range_noise_m**2
        self._yaw_var = s.yaw_noise_rad**2
        # diagonal process noise Q = dt q_rate + dt^2 q_rate2 (random walks; the gyro's white noise)
        self._q_rate = error_variances(
            s.attitude_random_walk_rad_sqrt_s,
            s.altitude_random_walk_m_sqrt_s,
            s.gyro_bias_walk_rad_s_sqrt_s,
            s.accel_bias_walk_m_s2_sqrt_s,
            s.velocity_random_walk_m_s_sqrt_s,
        )
        self._q_rate2 = np.r_[np.full(3, s.gyro_noise_rad_s**2), np.zeros(N_ERROR - 3)]
        # plain attributes for the 400 Hz calls
        self._gravity = s.gravity_m_s2
        self._motion_share = s.motion_accel_noise_share
        self._norm_tolerance = s.accel_norm_tolerance_m_s2
        self._gate3 = self._gate[3]
        compile_kernels(self)  # now, not on the first sample: see eskf_math.compile_kernels

    # ---- construction and resets --------------------------------------------------------------------

    def initial_state(self, q_world_body: npt.ArrayLike, pz_m: float, stamp_s: float) -> BiasEkfState:
        """A state at ``stamp_s``, at rest, zero biases, the settings' initial uncertainty."""
        qn, pz_m, stamp_s = check_initial(q_world_body, pz_m, stamp_s)
        s = self.settings
        diag = error_variances(
            s.initial_attitude_std_rad,
            s.initial_altitude_std_m,
            s.initial_gyro_bias_std_rad_s,
            s.initial_accel_bias_std_m_s2,
            s.initial_velocity_std_m_s,
        )
        return BiasEkfState.from_parts(qn, pz_m, _ZERO3, _ZERO3, np.diag(diag), stamp_s)

    def with_altitude(self, state: BiasEkfState, pz_m: float, std_m: float) -> BiasEkfState:
        """The state with the altitude replaced (uncorrelated, std ``std_m``): eq. 21 inverted at start."""
        P = with_reset_block(state.covariance, PZ, std_m**2)
        x = state.nominal.copy()
        x[kernels.PZ_X] = float(pz_m)
        return BiasEkfState(x, P, state.stamp_s)

    def with_position(self, state: BiasEkfState, p_xy_m: npt.ArrayLike, std_m: float) -> BiasEkfState:
        """The state with the horizontal position replaced (uncorrelated, std ``std_m``): the first visual
        position, or a reset after the position updates were refused for too long."""
        P = with_reset_block(state.covariance, PXY, std_m**2)
        x = state.nominal.copy()
        x[kernels.PXY_X : kernels.PXY_X + 2] = np.asarray(p_xy_m, dtype=np.float64).reshape(2)
        return BiasEkfState(x, P, state.stamp_s)

    # ---- read-outs ------------------------------------------------------------------------------------

    def attitude_covariance_world(self, state: BiasEkfState) -> FloatArray:
        """3x3 covariance of world-frame error angles (``R dtheta_body``)."""
        return attitude_covariance_world(state.q_world_body, state.covariance)

    def altitude_variance(self, state: BiasEkfState) -> float:
        return float(state.covariance[PZ, PZ])

    # ---- predict --------------------------------------------------------------------------------------

    def predict(
        self,
        state: BiasEkfState,
        gyro_rad_s: npt.ArrayLike,
        dt_s: float,
        accel_m_s2: npt.ArrayLike | None = None,
    ) -> BiasEkfState:
        """Bias-corrected gyro over ``dt_s``: nominal by eq. 12, covariance ``F P F^T + Q`` with
        ``F_theta_theta = I - [w dt]x``, ``F_theta_bg = -I dt``. With ``accel_m_s2`` the velocity and the
        position (altitude included) integrate ``a = R (f - b_a) - g e_z``, ``R`` at the interval's middle
        attitude (``F_v_theta = -(R [f - b_a]x) dt``, ``F_v_ba = -R dt``, ``F_p_v = I dt``); without it they
        keep a constant velocity."""
        gyro = _vector3(gyro_rad_s, "gyro_rad_s")
        use_accel = accel_m_s2 is not None
        accel = _vector3(accel_m_s2, "accel_m_s2") if accel_m_s2 is not None else _ZERO3
        check_duration(dt_s)
        status, x, P = kernels.predict_step(
            state.nominal, state.covariance, gyro, accel, use_accel, float(dt_s), self._q_rate, self._q_rate2,
            self._gravity,
        )  # fmt: skip
        if status != kernels.OK:
            _raise_for(status, "predict")
        return BiasEkfState(x, P, state.stamp_s + dt_s)

    def imu_step(
        self,
        state: BiasEkfState,
        gyro_rad_s: npt.ArrayLike,
        accel_m_s2: npt.ArrayLike,
        dt_s: float,
        measured_accel_m_s2: npt.ArrayLike | None,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> ImuStepResult[BiasEkfState]:
        """One IMU sample: :meth:`predict` with the interval's ``gyro_rad_s`` and ``accel_m_s2`` over
        ``dt_s``, then, unless ``measured_accel_m_s2`` is None, :meth:`update_accelerometer` with it, and the
        read-outs. Each kernel is called once."""
        measured = None if measured_accel_m_s2 is None else _vector3(measured_accel_m_s2, "accel_m_s2")
        mx, my, mz = motion_accel_world_m_s2
        predicted = self.predict(state, gyro_rad_s, dt_s, accel_m_s2)
        x, P = predicted.nominal, predicted.covariance
        accepted = None
        if measured is not None:
            status, _, xu, Pu = kernels.accelerometer_step(
                x, P, measured, float(mx), float(my), float(mz), self._gravity, self._accel_var,
                self._motion_share, self._norm_tolerance, self._gate3,
            )  # fmt: skip
            accepted = status == kernels.OK
            if accepted:
                x, P = xu, Pu
            elif status == kernels.NOT_FINITE:
                raise InputError(f"accel_m_s2 must be finite, got {measured.tolist()}")
            elif status not in (kernels.GATED, kernels.SKIPPED):
                _raise_for(status, "accelerometer update")
        covariance = attitude_covariance_world(x[0:4], P)
        return ImuStepResult(BiasEkfState(x, P, state.stamp_s + dt_s), accepted, covariance, float(P[PZ, PZ]))

    # ---- updates --------------------------------------------------------------------------------------

    def update_accelerometer(
        self,
        state: BiasEkfState,
        accel_m_s2: npt.ArrayLike,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> BiasUpdateResult:
        """Accelerometer: eq. 16 plus the bias, ``h = R^T (a + g e_z) + b_a`` (``dh/dtheta = [h]x``,
        ``dh/db_a = I``), its noise raised by ``motion_accel_noise_share`` times the compensated manoeuvre
        acceleration ``a``; skipped like the 5-state filter's when the bias-corrected specific force is
        far from the expected norm."""
        accel = _vector3(accel_m_s2, "accel_m_s2")
        mx, my, mz = motion_accel_world_m_s2
        status, nis, x, P = kernels.accelerometer_step(
            state.nominal, state.covariance, accel, float(mx), float(my), float(mz), self._gravity,
            self._accel_var, self._motion_share, self._norm_tolerance, self._gate3,
        )  # fmt: skip
        if status == kernels.OK:
            return BiasUpdateResult(BiasEkfState(x, P, state.stamp_s), True, nis)
        if status == kernels.NOT_FINITE:
            raise InputError(f"accel_m_s2 must be finite, got {accel.tolist()}")
        return self._result(state, status, nis, x, P, "accelerometer update")

    def update_position(
        self, state: BiasEkfState, p_xy_m: npt.ArrayLike, noise_m: float | None = None
    ) -> BiasUpdateResult:
        """Horizontal position ``p_xy_m`` (navigation frame, e.g. the visual odometry's), std ``noise_m``
        (default ``settings.position_noise_m``)."""
        std = self.settings.position_noise_m if noise_m is None else float(noise_m)
        p = checked_position(p_xy_m, std)
        PHt = np.ascontiguousarray(state.covariance[:, PXY])
        S = PHt[PXY] + np.eye(2) * std**2
        return self._correct(state, PHt, S, p - state.p_xy_m, "position update")

    def update_thrust_axis(
        self, state: BiasEkfState, mean_accel_xy_body_m_s2: npt.ArrayLike, n_samples: int
    ) -> BiasUpdateResult:
        """A multirotor's thrust is along its body z axis, so the body-horizontal specific force is the rotor
        drag alone (zero at hover): the mean body-horizontal accelerometer reading of ``n_samples`` samples
        measures the accelerometer bias, ``h = b_a,xy`` (``dh/db_a,xy = I``), with a noise of the averaged
        white noise, the settings' floor and ``rotor_drag_per_s`` times the body-horizontal speed. A tilt
        and a bias that read alike at hover separate: the tilt then shows as an acceleration in the visual
        position (as EKF2's multirotor drag fusion)."""
        f = np.asarray(mean_accel_xy_body_m_s2, dtype=np.float64).reshape(-1)
        if f.shape != (2,) or not np.all(np.isfinite(f)) or not n_samples >= 1:
            raise InputError(f"mean accel must be 2 finite numbers of >= 1 samples, got {f!r} ({n_samples})")
        s = self.settings
        v_world = state.nominal[kernels.VXY_X : kernels.VZ_X + 1]
        v_body = matrix_from_quaternion(state.q_world_body).T @ v_world
        var = (
            s.thrust_axis_sample_noise_m_s2**2 / n_samples
            + s.thrust_axis_floor_m_s2**2
            + (s.rotor_drag_per_s * float(np.hypot(v_body[0], v_body[1]))) ** 2
        )
        ba_xy = slice(BA.start, BA.start + 2)
        PHt = np.ascontiguousarray(state.covariance[:, ba_xy])
        S = PHt[ba_xy] + np.eye(2) * var
        return self._correct(state, PHt, S, f - state.accel_bias_m_s2[:2], "thrust-axis update")

    def update_yaw(
        self, state: BiasEkfState, yaw_rad: float, yaw_noise_rad: float | None = None
    ) -> BiasUpdateResult:
        """Yaw ``[cos psi, sin psi]`` of eq. 19 (:func:`.eskf_math.yaw_observation`)."""
        y, H = yaw_observation(state.q_world_body, yaw_rad)
        var = self._yaw_var if yaw_noise_rad is None else float(yaw_noise_rad) ** 2
        PHt = state.covariance @ H.T
        return self._correct(state, PHt, H @ PHt + np.eye(2) * var, y, "yaw update")

    def update_range(self, state: BiasEkfState, range_m: float) -> BiasUpdateResult:
        """Rangefinder with the tilt model of eq. 21 (:func:`.eskf_math.range_observation`)."""
        y, H = range_observation(state.q_world_body, state.pz_m, range_m)
        PHt = state.covariance @ H.T
        S = H @ PHt + np.array([[self._range_var]])
        return self._correct(state, PHt, S, y, "range update")

    def _correct(
        self, state: BiasEkfState, PHt: FloatArray, S: FloatArray, y: FloatArray, what: str
    ) -> BiasUpdateResult:
        """Gate, gain, ``(I - K H) P`` and injection of the error state (closed-form ``S^-1``, m <= 3)."""
        status, nis, x, P = kernels.correct_step(
            state.nominal, state.covariance, np.ascontiguousarray(PHt), np.ascontiguousarray(S),
            np.ascontiguousarray(y, dtype=np.float64), self._gate[y.shape[0]],
        )  # fmt: skip
        return self._result(state, status, nis, x, P, what)

    @staticmethod
    def _result(
        state: BiasEkfState, status: int, nis: float, x: FloatArray, P: FloatArray, what: str
    ) -> BiasUpdateResult:
        if status == kernels.OK:
            return BiasUpdateResult(BiasEkfState(x, P, state.stamp_s), True, nis)
        if status in (kernels.GATED, kernels.SKIPPED):
            return BiasUpdateResult(state, False, nis)
        _raise_for(status, what)
        raise EkfError(f"{what}: unexpected status {status}")
