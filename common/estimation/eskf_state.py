"""The error-state EKF's settings, state and update result (:mod:`common.estimation.eskf` is the filter).

Nominal state: ``q_world_body`` (unit, q0 >= 0), altitude ``pz_m``, gyro bias ``b_g`` (rad/s, body),
accelerometer bias ``b_a`` (m/s^2, body), the horizontal position ``p_xy_m`` and the velocity
``v_xy_m_s``, ``vz_m_s`` (navigation frame), as one vector (layout of
:mod:`~common.estimation.eskf_kernels`). Error state (15): body-frame attitude error ``dtheta``
(``q_true = q * [1, dtheta/2]``), ``dpz``, ``db_g``, ``db_a``, ``dp_xy``, ``dv_xy``, ``dvz``; 15x15
covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.bounds import bounded
from common.errors import InputError
from common.estimation import eskf_kernels as kernels
from common.estimation.ekf import EkfSettings
from common.types import FloatArray

#: Error-state layout.
THETA, PZ, BG, BA, PXY, VXY, VZ = slice(0, 3), 3, slice(4, 7), slice(7, 10), slice(10, 12), slice(12, 14), 14
N_ERROR = kernels.N_ERR


def error_variances(
    attitude_rad: float,
    altitude_m: float,
    gyro_bias_rad_s: float,
    accel_bias_m_s2: float,
    velocity_m_s: float,
) -> FloatArray:
    """The (N_ERROR,) diagonal of squares of per-block standard deviations (or random-walk densities), in the
    error-state layout: the same value on each axis of a block, 0 for the horizontal position."""
    diag = np.zeros(N_ERROR)
    diag[THETA] = attitude_rad**2
    diag[PZ] = altitude_m**2
    diag[BG] = gyro_bias_rad_s**2
    diag[BA] = accel_bias_m_s2**2
    diag[VXY] = diag[VZ] = velocity_m_s**2
    return diag


@dataclass(frozen=True)
class BiasEkfSettings(EkfSettings):
    """:class:`EkfSettings` plus the bias states' priors and random walks, and the inertial navigation's."""

    #: The gyro bias state replaces most of the attitude random walk that absorbs it in the 5-state filter.
    attitude_random_walk_rad_sqrt_s: float = bounded(0.0005, ge=0.0)
    initial_gyro_bias_std_rad_s: float = bounded(0.01, ge=0.0)
    initial_accel_bias_std_m_s2: float = bounded(0.1, ge=0.0)
    gyro_bias_walk_rad_s_sqrt_s: float = bounded(2e-5, ge=0.0)
    accel_bias_walk_m_s2_sqrt_s: float = bounded(2e-4, ge=0.0)
    #: Horizontal velocity: initial std and random walk (the accelerometer's white noise integrated).
    initial_velocity_std_m_s: float = bounded(0.5, ge=0.0)
    velocity_random_walk_m_s_sqrt_s: float = bounded(0.01, ge=0.0)
    #: Std of the horizontal position measurement (the visual odometry's free chain) per frame.
    position_noise_m: float = bounded(0.01, gt=0.0)
    #: The accelerometer's noise grows by this share of the compensated manoeuvre acceleration: that VO fit is
    #: about as uncertain as it is large, the VO-aided inertial navigation the better tilt reference then. 10,
    #: not 1 (estimator seed sweep): agile seeds 0-9 RPE 0.221 -> 0.168 %/m, paper C ATE 0.506 -> 0.516 cm.
    motion_accel_noise_share: float = bounded(10.0, ge=0.0)
    #: Multirotor thrust-axis model (:meth:`BiasAwareEkf.update_thrust_axis`): the accelerometer's white
    #: noise per sample, a floor for what the model leaves out (vibration, asymmetric thrust) and the rotor
    #: drag per unit of body-horizontal speed (its specific force, left out of the model, raises the noise).
    thrust_axis_sample_noise_m_s2: float = bounded(0.08, gt=0.0)
    thrust_axis_floor_m_s2: float = bounded(0.02, ge=0.0)
    rotor_drag_per_s: float = bounded(0.3, ge=0.0)


@dataclass(frozen=True)
class BiasEkfState:
    """Nominal state at ``stamp_s`` as one vector (layout of :mod:`~common.estimation.eskf_kernels`, read
    through the named properties; never modified in place) and the 15x15 error-state covariance (layout
    :data:`THETA` ...)."""

    nominal: FloatArray
    covariance: FloatArray
    stamp_s: float

    @classmethod
    def from_parts(
        cls,
        q_world_body: npt.ArrayLike,
        pz_m: float,
        gyro_bias_rad_s: npt.ArrayLike,
        accel_bias_m_s2: npt.ArrayLike,
        covariance: npt.ArrayLike,
        stamp_s: float,
        p_xy_m: npt.ArrayLike = (0.0, 0.0),
        v_xy_m_s: npt.ArrayLike = (0.0, 0.0),
        vz_m_s: float = 0.0,
    ) -> BiasEkfState:
        nominal = np.concatenate(
            [
                np.asarray(q_world_body, dtype=np.float64).reshape(4),
                [float(pz_m)],
                np.asarray(gyro_bias_rad_s, dtype=np.float64).reshape(3),
                np.asarray(accel_bias_m_s2, dtype=np.float64).reshape(3),
                np.asarray(p_xy_m, dtype=np.float64).reshape(2),
                np.asarray(v_xy_m_s, dtype=np.float64).reshape(2),
                [float(vz_m_s)],
            ]
        )
        P = np.array(covariance, dtype=np.float64)
        if P.shape != (N_ERROR, N_ERROR):
            raise InputError(f"covariance must have shape ({N_ERROR}, {N_ERROR}), got {P.shape}")
        return cls(nominal, P, float(stamp_s))

    @property
    def q_world_body(self) -> FloatArray:
        return self.nominal[0:4]

    @property
    def pz_m(self) -> float:
        return float(self.nominal[4])

    @property
    def gyro_bias_rad_s(self) -> FloatArray:
        return self.nominal[5:8]

    @property
    def accel_bias_m_s2(self) -> FloatArray:
        return self.nominal[8:11]

    @property
    def p_xy_m(self) -> FloatArray:
        return self.nominal[11:13]

    @property
    def v_xy_m_s(self) -> FloatArray:
        return self.nominal[13:15]

    @property
    def vz_m_s(self) -> float:
        return float(self.nominal[15])


@dataclass(frozen=True)
class BiasUpdateResult:
    """Outcome of one update: the new state, whether the gate accepted it, and its NIS."""

    state: BiasEkfState
    accepted: bool
    nis: float
