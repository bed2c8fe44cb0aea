"""Small closed forms of the error-state EKF (:mod:`common.estimation.eskf`): the error Jacobian of the
quaternion, the inverse of a 1x1-3x3 innovation covariance, the rotation matrix as floats and the injection
of a body-frame attitude error."""

from __future__ import annotations

import numpy as np

from common.estimation.ekf_models import EkfError, normalized_quaternion
from common.types import FloatArray

Quaternion = tuple[float, float, float, float]


def error_jacobian(q: Quaternion) -> FloatArray:
    """``dq/dtheta`` (4x3) of ``q * [1, dtheta/2]`` at ``dtheta = 0``: ``1/2 [-q_v^T; q0 I + [q_v]x]``."""
    q0, q1, q2, q3 = q
    return 0.5 * np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


def rotation_rows(q: Quaternion) -> tuple[float, float, float, float, float, float, float, float, float]:
    """``R_world_body`` of a unit quaternion, row-major, as floats."""
    q0, q1, q2, q3 = q
    return (
        1.0 - 2.0 * (q2 * q2 + q3 * q3), 2.0 * (q1 * q2 - q0 * q3), 2.0 * (q1 * q3 + q0 * q2),
        2.0 * (q1 * q2 + q0 * q3), 1.0 - 2.0 * (q1 * q1 + q3 * q3), 2.0 * (q2 * q3 - q0 * q1),
        2.0 * (q1 * q3 - q0 * q2), 2.0 * (q2 * q3 + q0 * q1), 1.0 - 2.0 * (q1 * q1 + q2 * q2),
    )  # fmt: skip


def inject_attitude(q: Quaternion, dx: float, dy: float, dz: float) -> Quaternion:
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


def inverse_spd(S: FloatArray) -> FloatArray:
    """Closed-form inverse of a 1x1, 2x2 or 3x3 innovation covariance (EkfError if not positive definite)."""
    m = S.shape[0]
    if m == 1:
        s00 = float(S[0, 0])
        if not s00 > 0.0:
            raise EkfError(f"innovation variance {s00} is not positive")
        return np.array([[1.0 / s00]])
    if m == 2:
        (s00, s01), (s10, s11) = S.tolist()
        s01 = 0.5 * (s01 + s10)
        det = s00 * s11 - s01 * s01
        if not det > 0.0:
            raise EkfError(f"innovation covariance is not positive definite (det {det})")
        return np.array([[s11, -s01], [-s01, s00]], dtype=np.float64) / float(det)
    (s00, s01, s02), (_, s11, s12), (_, _, s22) = S.tolist()
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not det > 0.0:
        raise EkfError(f"innovation covariance is not positive definite (det {det})")
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    return np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]], dtype=np.float64) / float(det)
