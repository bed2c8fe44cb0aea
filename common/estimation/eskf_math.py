"""Small closed forms of the error-state EKF (:mod:`common.estimation.eskf`): the error Jacobian of the
quaternion and the inverse of a 1x1-3x3 innovation covariance."""

from __future__ import annotations

import numpy as np

from common.estimation.ekf_models import EkfError
from common.estimation.eskf_kernels import inverse_small
from common.types import FloatArray

Quaternion = tuple[float, float, float, float]


def error_jacobian(q: Quaternion) -> FloatArray:
    """``dq/dtheta`` (4x3) of ``q * [1, dtheta/2]`` at ``dtheta = 0``: ``1/2 [-q_v^T; q0 I + [q_v]x]``."""
    q0, q1, q2, q3 = q
    return 0.5 * np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def inverse_spd(S: FloatArray) -> FloatArray:
    """Closed-form inverse of a 1x1, 2x2 or 3x3 innovation covariance (EkfError if not positive definite)."""
    ok, out = inverse_small(S)
    if not ok:
        raise EkfError(f"innovation covariance {np.asarray(S).tolist()} is not positive definite")
    return out
