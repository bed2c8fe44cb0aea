"""Small closed forms of the error-state EKF (:mod:`common.estimation.eskf`): the error Jacobian of the
quaternion, the inverse of a 1x1-3x3 innovation covariance and the attitude's covariance in the world."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from common.estimation.ekf_models import EkfError
from common.estimation.eskf_kernels import inverse_small
from common.geometry import matrix_from_quaternion
from common.types import FloatArray

if TYPE_CHECKING:
    from common.estimation.eskf import BiasAwareEkf

Quaternion = tuple[float, float, float, float]


def error_jacobian(q: Quaternion) -> FloatArray:
    """``dq/dtheta`` (4x3) of ``q * [1, dtheta/2]`` at ``dtheta = 0``: ``1/2 [-q_v^T; q0 I + [q_v]x]``."""
    q0, q1, q2, q3 = q
    return 0.5 * np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def attitude_covariance_world(q_world_body: FloatArray, covariance: FloatArray) -> FloatArray:
    """3x3 covariance of world-frame error angles (``R dtheta_body``) from the error state's covariance."""
    R = matrix_from_quaternion(q_world_body)
    C = R @ covariance[0:3, 0:3] @ R.T
    return np.asarray(0.5 * (C + C.T), dtype=np.float64)


def inverse_spd(S: FloatArray) -> FloatArray:
    """Closed-form inverse of a 1x1, 2x2 or 3x3 innovation covariance (EkfError if not positive definite)."""
    ok, out = inverse_small(S)
    if not ok:
        raise EkfError(f"innovation covariance {np.asarray(S).tolist()} is not positive definite")
    return out


def compile_kernels(ekf: BiasAwareEkf) -> None:
    """Call each compiled kernel once on a level state at rest, so that numba builds them (or loads them
    from its disk cache) when the filter is built: a first call compiles for tens of seconds on a busy host,
    and a service builds its filter before it subscribes (a cold compile after subscribing let the
    estimator's queues overflow and the filter diverge: the docker run's roll/pitch 37 deg RMS)."""
    gravity = np.array([0.0, 0.0, ekf.settings.gravity_m_s2])
    state = ekf.initial_state(np.array([1.0, 0.0, 0.0, 0.0]), 1.0, 0.0)
    state = ekf.predict(state, np.zeros(3), 0.0025, gravity)
    ekf.update_accelerometer(state, gravity)
    ekf.update_position(state, np.zeros(2))
