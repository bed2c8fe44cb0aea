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
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

from common.bounds import Bounded, bounded, check_duration
from common.errors import InputError
from common.estimation.chi_square import chi_square_quantile
from common.estimation.ekf_models import (
    STANDARD_GRAVITY_M_S2,
    Corrected,
    EkfError,
    accelerometer_step,
    check_initial,
    correct_step,
    error_angle_covariance_world,
    predict_step,
    rangefinder_model,
    with_reset_block,
    yaw_model,
)
from common.types import FloatArray

StateT = TypeVar("StateT")

__all__ = [
    "STANDARD_GRAVITY_M_S2",
    "AttitudeAltitudeEkf",
    "EkfError",
    "EkfSettings",
    "EkfState",
    "ImuStepResult",
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


@dataclass(frozen=True)
class ImuStepResult(Generic[StateT]):
    """One IMU sample through a filter (``imu_step``, either filter): the state after the predict and the
    accelerometer update, whether the gate accepted that update (None: not asked for), and the read-outs of
    the new state (:meth:`~AttitudeAltitudeEkf.attitude_covariance_world`, the altitude variance)."""

    state: StateT
    accepted: bool | None
    attitude_covariance_world: FloatArray
    altitude_var_m2: float


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
        qn, P = predict_step(
            state.q_world_body, state.covariance, gyro_rad_s, dt_s, self._gyro_var, self._attitude_rw_var,
            self._altitude_rw_var,
        )  # fmt: skip
        return EkfState(np.array(qn), state.pz_m, P, state.stamp_s + dt_s)

    def imu_step(
        self,
        state: EkfState,
        gyro_rad_s: npt.ArrayLike,
        accel_m_s2: npt.ArrayLike,
        dt_s: float,
        measured_accel_m_s2: npt.ArrayLike | None,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> ImuStepResult[EkfState]:
        """One IMU sample: :meth:`predict` with the interval's ``gyro_rad_s`` over ``dt_s`` (``accel_m_s2`` is
        not used), then, unless ``measured_accel_m_s2`` is None, :meth:`update_accelerometer` with it, and the
        read-outs; one call into the model module (:mod:`common.estimation.ekf_models`)."""
        new = self.predict(state, gyro_rad_s, dt_s)
        P = new.covariance
        accepted = None
        if measured_accel_m_s2 is not None:
            s = self.settings
            _, corrected = accelerometer_step(
                new.q_world_body, new.pz_m, P, measured_accel_m_s2, motion_accel_world_m_s2, s.gravity_m_s2,
                s.accel_norm_tolerance_m_s2, self._accel_var, self._gate[3],
            )  # fmt: skip
            accepted = corrected is not None
            if corrected is not None:
                q, pz_m, P = corrected
                new = EkfState(np.array(q), pz_m, P, new.stamp_s)
        covariance = error_angle_covariance_world(new.q_world_body, P[:4, :4])
        return ImuStepResult(new, accepted, covariance, float(P[4, 4]))

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
        s = self.settings
        nis, corrected = accelerometer_step(
            state.q_world_body, state.pz_m, state.covariance, accel_m_s2, motion_accel_world_m_s2,
            s.gravity_m_s2, s.accel_norm_tolerance_m_s2, self._accel_var, self._gate[3],
        )  # fmt: skip
        return self._result(state, nis, corrected)

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
        y = (math.cos(yaw_rad) - h[0], math.sin(yaw_rad) - h[1])
        return self._result(
            state, *correct_step(state.q_world_body, state.pz_m, state.covariance, y, H, var, self._gate[2])
        )

    def update_range(self, state: EkfState, range_m: float) -> UpdateResult:
        """Rangefinder update with the tilt model of paper C eq. 21 (eqs. 4-8)."""
        if not (math.isfinite(range_m) and range_m > 0.0):
            raise InputError(f"range_m must be finite and > 0, got {range_m}")
        q = state.q_world_body.tolist()
        h, Hrow = rangefinder_model((q[0], q[1], q[2], q[3]), state.pz_m)
        H = np.array([Hrow])
        nis, corrected = correct_step(
            state.q_world_body,
            state.pz_m,
            state.covariance,
            (range_m - h,),
            H,
            self._range_var,
            self._gate[1],
        )
        return self._result(state, nis, corrected)

    @staticmethod
    def _result(state: EkfState, nis: float, corrected: Corrected) -> UpdateResult:
        """An update's result: the corrected state, or ``state`` when the gate refused (or skipped) it."""
        if corrected is None:
            return UpdateResult(state=state, accepted=False, nis=nis)
        q, pz_m, P = corrected
        return UpdateResult(EkfState(np.array(q), pz_m, P, state.stamp_s), accepted=True, nis=nis)
