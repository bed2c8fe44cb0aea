"""Rotations and frames, shared by every core.

Conventions (fixed for the whole package):

- Quaternions are Hamilton, scalar first: ``q = [q0, q1, q2, q3] = [w, x, y, z]``.
  ``q_world_body`` rotates body vectors into the world: ``v_world = R_world_body @ v_body``.
- World frame: x east, y north, z up (ENU); the ground plane is ``z = 0``.
- Body frame: x forward, y left, z up (FLU). Yaw is the ZYX Euler angle about world z,
  positive counter-clockwise seen from above; roll about x, pitch about y.
- Camera frame (OpenCV): x right, y down, z along the optical axis.
- Angles are radians unless a name says ``_deg``.

All functions accept a single item or a batch along leading axes where noted.
"""

from __future__ import annotations

from enum import StrEnum

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.types import FloatArray


def constant(values: npt.ArrayLike) -> FloatArray:
    """A read-only float array: module constants are shared (and are default arguments), so nobody may
    write into them."""
    array = np.array(values, dtype=float)
    array.setflags(write=False)
    return array


#: Downward camera on the body: image right = body right (-y), image down = body backward (-x),
#: optical axis = body down (-z).
R_BODY_CAMERA_DOWN: FloatArray = constant([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Forward camera on the body: image right = body right (-y), image down = body down (-z),
#: optical axis = body forward (+x).
R_BODY_CAMERA_FORWARD: FloatArray = constant([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


class CameraMount(StrEnum):
    """How the camera sits on the body (the localizer's setting)."""

    FORWARD = "forward"
    DOWN = "down"

    @property
    def R_body_camera(self) -> FloatArray:
        """:data:`R_BODY_CAMERA_FORWARD` or :data:`R_BODY_CAMERA_DOWN`."""
        return R_BODY_CAMERA_FORWARD if self is CameraMount.FORWARD else R_BODY_CAMERA_DOWN


def check_quaternion(q: npt.ArrayLike, name: str = "q") -> FloatArray:
    """Return ``q`` as float64 of shape (..., 4) with finite, non-zero norm, or raise InputError."""
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 4:
        raise InputError(f"{name} must have shape (..., 4), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite, got {arr}")
    if np.any(np.linalg.norm(arr, axis=-1) < 1e-12):
        raise InputError(f"{name} must have a non-zero norm")
    return arr


def check_rotation_matrix(R: npt.ArrayLike, name: str = "R", tol: float = 1e-6) -> FloatArray:
    """Return ``R`` as float64 (..., 3, 3) if orthonormal with det +1, or raise InputError."""
    arr = np.asarray(R, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[-2:] != (3, 3):
        raise InputError(f"{name} must have shape (..., 3, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite")
    eye = np.eye(3)
    if not np.allclose(np.swapaxes(arr, -1, -2) @ arr, eye, atol=tol):
        raise InputError(f"{name} is not orthonormal")
    if np.any(np.linalg.det(arr) < 0.0):
        raise InputError(f"{name} has determinant -1 (a reflection)")
    return arr


def normalize_quaternion(q: npt.ArrayLike) -> FloatArray:
    """Unit quaternion with non-negative scalar part (one sign for each rotation)."""
    arr = check_quaternion(q)
    arr = arr / np.linalg.norm(arr, axis=-1, keepdims=True)
    sign = np.where(arr[..., :1] < 0.0, -1.0, 1.0)
    return np.asarray(arr * sign, dtype=np.float64)


def quaternion_multiply(q_a_b: npt.ArrayLike, q_b_c: npt.ArrayLike) -> FloatArray:
    """Hamilton product ``q_a_c = q_a_b * q_b_c`` (batched)."""
    a = np.asarray(q_a_b, dtype=np.float64)
    b = np.asarray(q_b_c, dtype=np.float64)
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def quaternion_conjugate(q: npt.ArrayLike) -> FloatArray:
    """Inverse rotation of a unit quaternion."""
    arr = np.array(q, dtype=np.float64)
    arr[..., 1:] *= -1.0
    return arr


def matrix_from_quaternion(q: npt.ArrayLike) -> FloatArray:
    """Rotation matrix ``R_world_body`` of a (not necessarily unit) quaternion (batched)."""
    arr = np.asarray(q, dtype=np.float64)
    arr = arr / np.linalg.norm(arr, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(arr, -1, 0)
    R = np.empty((*arr.shape[:-1], 3, 3))
    R[..., 0, 0] = w * w + x * x - y * y - z * z
    R[..., 0, 1] = 2.0 * (x * y - w * z)
    R[..., 0, 2] = 2.0 * (x * z + w * y)
    R[..., 1, 0] = 2.0 * (x * y + w * z)
    R[..., 1, 1] = w * w - x * x + y * y - z * z
    R[..., 1, 2] = 2.0 * (y * z - w * x)
    R[..., 2, 0] = 2.0 * (x * z - w * y)
    R[..., 2, 1] = 2.0 * (y * z + w * x)
    R[..., 2, 2] = w * w - x * x - y * y + z * z
    return R


def quaternion_from_matrix(R: npt.ArrayLike) -> FloatArray:
    """Unit quaternion (scalar part >= 0) of a rotation matrix (single matrix)."""
    m = check_rotation_matrix(R)
    if m.shape != (3, 3):
        raise InputError(f"quaternion_from_matrix takes one (3, 3) matrix, got {m.shape}")
    trace = np.trace(m)
    if trace > 0.0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return normalize_quaternion(q)


def matrix_from_euler(roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike) -> FloatArray:
    """``R_world_body = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (ZYX), batched over broadcast inputs."""
    r, p, y = np.broadcast_arrays(
        np.asarray(roll, dtype=np.float64),
        np.asarray(pitch, dtype=np.float64),
        np.asarray(yaw, dtype=np.float64),
    )
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty((*r.shape, 3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def quaternion_from_euler(roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike) -> FloatArray:
    """ZYX Euler angles to a unit quaternion with q0 >= 0 (batched)."""
    r, p, y = np.broadcast_arrays(
        np.asarray(roll, dtype=np.float64) / 2.0,
        np.asarray(pitch, dtype=np.float64) / 2.0,
        np.asarray(yaw, dtype=np.float64) / 2.0,
    )
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    q = np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )
    return normalize_quaternion(q)


def euler_from_quaternion(q: npt.ArrayLike) -> FloatArray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` of a quaternion (batched, shape (..., 3))."""
    R = matrix_from_quaternion(check_quaternion(q))
    return euler_from_matrix(R)


def euler_from_matrix(R: npt.ArrayLike) -> FloatArray:
    """ZYX Euler angles ``[roll, pitch, yaw]`` of ``R_world_body`` (batched, shape (..., 3))."""
    m = np.asarray(R, dtype=np.float64)
    roll = np.arctan2(m[..., 2, 1], m[..., 2, 2])
    pitch = np.arcsin(np.clip(-m[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def quaternion_from_rotation_vector(rotvec: npt.ArrayLike) -> FloatArray:
    """Exponential map: rotation vector (axis * angle, rad) to a unit quaternion (batched)."""
    v = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle with its limit 1/2 at zero
    scale = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), v * scale], axis=-1)


def rotation_vector_from_quaternion(q: npt.ArrayLike) -> FloatArray:
    """Logarithmic map: unit quaternion to rotation vector with angle in [0, pi] (batched)."""
    u = normalize_quaternion(q)
    vec = u[..., 1:]
    s = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, u[..., :1])
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return np.asarray(vec * scale, dtype=np.float64)


def wrap_angle_rad(angle_rad: npt.ArrayLike) -> FloatArray:
    """Wrap angles to [-pi, pi)."""
    a = np.asarray(angle_rad, dtype=np.float64)
    return np.asarray((a + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def skew(v: npt.ArrayLike) -> FloatArray:
    """Cross-product matrix ``[v]x`` such that ``skew(a) @ b == cross(a, b)``."""
    x, y, z = np.asarray(v, dtype=np.float64)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
