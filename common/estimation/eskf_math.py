"""Small closed forms of the error-state EKF (:mod:`common.estimation.eskf`): the error Jacobian of the
quaternion, the inverse of a 1x1-3x3 innovation covariance, the attitude's covariance in the world, and the
checked inputs, innovations and error-state Jacobians of the position, yaw and range updates of paper C (the
filter and its test reference both take them from here)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.estimation.ekf_models import EkfError, rangefinder_model, yaw_model
from common.estimation.eskf_kernels import inverse_small
from common.estimation.eskf_state import N_ERROR, PZ, THETA
from common.geometry import matrix_from_quaternion
from common.types import FloatArray

if TYPE_CHECKING:
    from common.estimation.eskf import BiasAwareEkf

Quaternion = tuple[float, float, float, float]


def error_jacobian(q: Quaternion) -> FloatArray:
    """``dq/dtheta`` (4x3) of ``q * [1, dtheta/2]`` at ``dtheta = 0``: ``1/2 [-q_v^T; q0 I + [q_v]x]``."""
    q0, q1, q2, q3 = q
    return 0.5 * np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def checked_position(p_xy_m: npt.ArrayLike, noise_m: float) -> FloatArray:
    """A horizontal position measurement as (2,), once it and its std are checked (InputError naming what is
    wrong)."""
    p = np.asarray(p_xy_m, dtype=np.float64).reshape(-1)
    if p.shape != (2,) or not np.all(np.isfinite(p)):
        raise InputError(f"p_xy_m must be 2 finite numbers, got {p_xy_m!r}")
    if not (math.isfinite(noise_m) and noise_m > 0.0):
        raise InputError(f"position noise must be finite and > 0, got {noise_m}")
    return p


def yaw_observation(q_world_body: FloatArray, yaw_rad: float) -> tuple[FloatArray, FloatArray]:
    """Innovation (2,) of the yaw ``[cos psi, sin psi]`` of eq. 19 (``yaw_rad`` may be unwrapped) and its
    error-state Jacobian (2, N_ERROR)."""
    if not math.isfinite(yaw_rad):
        raise InputError(f"yaw_rad must be finite, got {yaw_rad}")
    q = q_world_body.tolist()
    qt = (q[0], q[1], q[2], q[3])
    h, Hq = yaw_model(qt)
    H = np.zeros((2, N_ERROR))
    H[:, THETA] = np.array(Hq) @ error_jacobian(qt)
    return np.array([math.cos(yaw_rad) - h[0], math.sin(yaw_rad) - h[1]]), H


def range_observation(q_world_body: FloatArray, pz_m: float, range_m: float) -> tuple[FloatArray, FloatArray]:
    """Innovation (1,) of a rangefinder reading with the tilt model of eq. 21 and its error-state Jacobian
    (1, N_ERROR)."""
    if not (math.isfinite(range_m) and range_m > 0.0):
        raise InputError(f"range_m must be finite and > 0, got {range_m}")
    q = q_world_body.tolist()
    qt = (q[0], q[1], q[2], q[3])
    h, Hrow = rangefinder_model(qt, pz_m)
    H = np.zeros((1, N_ERROR))
    H[0, THETA] = np.array(Hrow[:4]) @ error_jacobian(qt)
    H[0, PZ] = Hrow[4]
    return np.array([range_m - h]), H


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
