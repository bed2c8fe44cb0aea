"""The two attitude/altitude filters behind one set of functions: paper C's 5-state EKF (the reference) and
the error-state EKF with bias states. The coupling holds either; these dispatch on the pair it holds."""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np

from common.estimation.coupling_types import EkfKind
from common.estimation.ekf import AttitudeAltitudeEkf, EkfSettings, EkfState
from common.estimation.ekf_models import EkfError, propagate_quaternion
from common.estimation.eskf import BiasAwareEkf, BiasEkfSettings, BiasEkfState
from common.types import FloatArray

AnyFilter = AttitudeAltitudeEkf | BiasAwareEkf
AnyState = EkfState | BiasEkfState


def make_filter(kind: EkfKind, settings: EkfSettings | None = None) -> AnyFilter:
    """The filter of ``kind`` (``settings`` of the matching type, else its defaults)."""
    if kind is EkfKind.BIAS:
        return BiasAwareEkf(settings if isinstance(settings, BiasEkfSettings) else None)
    return AttitudeAltitudeEkf(settings)


def _call(ekf: AnyFilter, state: AnyState, method: str, *args: Any) -> Any:
    """``ekf.method(state, *args)`` (both filters share the names) once the state is the filter's kind."""
    if not (
        (isinstance(state, BiasEkfState) and isinstance(ekf, BiasAwareEkf))
        or (isinstance(state, EkfState) and isinstance(ekf, AttitudeAltitudeEkf))
    ):
        raise EkfError("filter and state kinds differ")
    return getattr(ekf, method)(state, *args)


def with_altitude(ekf: AnyFilter, state: AnyState, pz_m: float, std_m: float) -> AnyState:
    """The state with its altitude replaced (uncorrelated, std ``std_m``)."""
    return cast(AnyState, _call(ekf, state, "with_altitude", pz_m, std_m))


def attitude_covariance(ekf: AnyFilter, state: AnyState) -> FloatArray:
    """3x3 covariance of world-frame error angles."""
    return cast(FloatArray, _call(ekf, state, "attitude_covariance_world"))


def altitude_variance(ekf: AnyFilter, state: AnyState) -> float:
    return float(_call(ekf, state, "altitude_variance"))


def filter_step(ekf: AnyFilter, state: AnyState, method: str, *args: Any) -> tuple[AnyState, bool]:
    """One filter call (``predict`` or an ``update_*``; both filters share the names): the new state and
    whether the update passed its gate."""
    result = getattr(ekf, method)(state, *args)
    if method == "predict":
        return result, True
    return result.state, bool(result.accepted)


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
