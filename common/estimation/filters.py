"""The two attitude/altitude filters behind one :class:`AttitudeFilter` protocol: paper C's 5-state EKF (the
reference) and the error-state EKF with bias states. The coupling holds either and calls its methods directly;
each method takes a state and returns a new one (or an :class:`Update` or :class:`ImuStepResult` carrying it).
An IMU sample is one call, :meth:`AttitudeFilter.imu_step`."""

from __future__ import annotations

import math
from typing import Any, Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from common.estimation.coupling_types import EkfKind
from common.estimation.ekf import AttitudeAltitudeEkf, EkfSettings, EkfState, ImuStepResult
from common.estimation.ekf_models import propagate_quaternion
from common.estimation.eskf import BiasAwareEkf
from common.estimation.eskf_state import BiasEkfSettings, BiasEkfState
from common.types import FloatArray

AnyState = EkfState | BiasEkfState
S = TypeVar("S", bound=AnyState)
S_co = TypeVar("S_co", bound=AnyState, covariant=True)


class Update(Protocol[S_co]):
    """Outcome of one measurement update: the new state, whether the gate accepted it, its NIS."""

    @property
    def state(self) -> S_co: ...
    @property
    def accepted(self) -> bool: ...
    @property
    def nis(self) -> float: ...


class AttitudeFilter(Protocol[S]):
    """What the coupling calls on a filter: state in, state out."""

    @property
    def settings(self) -> EkfSettings: ...

    def initial_state(self, q_world_body: npt.ArrayLike, pz_m: float, stamp_s: float) -> S: ...

    def predict(
        self, state: S, gyro_rad_s: npt.ArrayLike, dt_s: float, accel_m_s2: npt.ArrayLike | None = None
    ) -> S: ...

    def update_accelerometer(
        self,
        state: S,
        accel_m_s2: npt.ArrayLike,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Update[S]: ...

    def imu_step(
        self,
        state: S,
        gyro_rad_s: npt.ArrayLike,
        accel_m_s2: npt.ArrayLike,
        dt_s: float,
        measured_accel_m_s2: npt.ArrayLike | None,
        motion_accel_world_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> ImuStepResult[S]:
        """:meth:`predict` then (unless ``measured_accel_m_s2`` is None) :meth:`update_accelerometer`, with
        the new state's read-outs: the whole of one IMU sample."""
        ...

    def update_yaw(self, state: S, yaw_rad: float, yaw_noise_rad: float | None = None) -> Update[S]: ...

    def update_range(self, state: S, range_m: float) -> Update[S]: ...

    def with_altitude(self, state: S, pz_m: float, std_m: float) -> S: ...

    def attitude_covariance_world(self, state: S) -> FloatArray: ...

    def altitude_variance(self, state: S) -> float: ...


def make_filter(kind: EkfKind, settings: EkfSettings | None = None) -> AttitudeFilter[Any]:
    """The filter of ``kind`` (``settings`` of the matching type, else its defaults)."""
    if kind is EkfKind.BIAS:
        return BiasAwareEkf(settings if isinstance(settings, BiasEkfSettings) else None)
    return AttitudeAltitudeEkf(settings)


def tilt_std_rad(attitude_covariance_world: FloatArray) -> float:
    """Largest standard deviation of the horizontal (tilt) error angles."""
    C = np.asarray(attitude_covariance_world, dtype=np.float64)[:2, :2]
    return float(math.sqrt(max(float(np.linalg.eigvalsh(C)[-1]), 0.0)))


def smoothed_attitude(
    q_prev: FloatArray, gyro_rad_s: FloatArray, dt_s: float, q_filter: FloatArray, tau_s: float
) -> FloatArray:
    """The gyro's rotation over ``dt_s`` (eq. 12) applied to ``q_prev``, pulled towards the filter's
    ``q_filter`` with the time constant ``tau_s``: an attitude that rectifies consecutive frames
    consistently (the accelerometer corrections would otherwise make them jitter against each other)."""
    half = 0.5 * dt_s
    r = q_prev.tolist()
    w = gyro_rad_s
    q = np.array(propagate_quaternion((r[0], r[1], r[2], r[3]), half * w[0], half * w[1], half * w[2]))
    target = q_filter if float(np.dot(q, q_filter)) >= 0.0 else -q_filter
    alpha = min(1.0, dt_s / tau_s)
    q = (1.0 - alpha) * q + alpha * target
    return np.asarray(q / np.linalg.norm(q), dtype=np.float64)
