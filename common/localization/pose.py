"""Camera poses of the localizer: the one place where pose conventions are converted.

Internally a pose is a camera centre ``p_world_camera_m`` (3,) and a rotation matrix ``R_world_camera``
(3, 3) (OpenCV camera frame: x right, y down, z along the optical axis). Rotations are never stored as Euler
angles, so there is no gimbal lock; perturbations are applied on the left by the exponential map of a
world-frame rotation vector, ``R' = Exp(dtheta) R`` (:func:`perturb`).

Conventions accepted at the edges (``--initial-pose``, the bench, files):

- **camera-from-world 4x4** ``T_camera_world``: ``X_camera = R_camera_world X_world + t_camera_world``;
- **OpenCV rvec + tvec** (``cv2.solvePnP``'s output, ViSP's ``cMo``): ``R_camera_world = Rodrigues(rvec)``,
  ``t_camera_world = tvec`` (metres);
- **body state** ``(x, y, z, roll, pitch, yaw)``: the body in the world with ZYX Euler angles of
  ``R_world_body``, the camera mounted by ``R_body_camera`` (the office simulation's and paper B's state).

``R_world_camera = R_camera_world^T`` and ``p_world_camera = -R_world_camera t_camera_world``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import euler_from_matrix, matrix_from_euler
from common.types import FloatArray


@dataclass(frozen=True)
class CameraPose:
    """One camera pose: centre ``p_world_camera_m`` (3,) and ``R_world_camera`` (3, 3)."""

    p_world_camera_m: FloatArray
    R_world_camera: FloatArray

    def __post_init__(self) -> None:
        p = np.asarray(self.p_world_camera_m, dtype=np.float64)
        R = np.asarray(self.R_world_camera, dtype=np.float64)
        if p.shape != (3,) or R.shape != (3, 3) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            raise InputError(f"a camera pose needs a finite (3,) centre and (3, 3) rotation, got {p.shape}")
        if np.max(np.abs(R @ R.T - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0.0:
            raise InputError("R_world_camera must be a rotation matrix (orthonormal, det +1)")
        object.__setattr__(self, "p_world_camera_m", p)
        object.__setattr__(self, "R_world_camera", R)

    @property
    def R_camera_world(self) -> FloatArray:
        return np.asarray(self.R_world_camera.T)

    @property
    def t_camera_world_m(self) -> FloatArray:
        return np.asarray(-self.R_camera_world @ self.p_world_camera_m)

    # -- conversions in ---------------------------------------------------------------------------------
    @classmethod
    def from_T_camera_world(cls, T: npt.ArrayLike) -> CameraPose:
        """Pose of a camera-from-world 4x4 matrix (last row 0 0 0 1)."""
        M = np.asarray(T, dtype=np.float64)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise InputError(f"T_camera_world must be a finite 4x4 matrix, got shape {M.shape}")
        if np.max(np.abs(M[3] - [0.0, 0.0, 0.0, 1.0])) > 1e-9:
            raise InputError(f"the last row of T_camera_world must be 0 0 0 1, got {M[3].tolist()}")
        R_camera_world = M[:3, :3]
        return cls(-R_camera_world.T @ M[:3, 3], R_camera_world.T)

    @classmethod
    def from_rvec_tvec(cls, rvec: npt.ArrayLike, tvec_m: npt.ArrayLike) -> CameraPose:
        """Pose of OpenCV's camera-from-world rotation vector (rad) and translation (m)."""
        r = np.asarray(rvec, dtype=np.float64).reshape(-1)
        t = np.asarray(tvec_m, dtype=np.float64).reshape(-1)
        if r.shape != (3,) or t.shape != (3,) or not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
            raise InputError("rvec and tvec must be 3 finite numbers each")
        R_camera_world = rotation_matrices(r[None, :])[0]
        return cls(-R_camera_world.T @ t, R_camera_world.T)

    @classmethod
    def from_body_state(cls, state: npt.ArrayLike, R_body_camera: npt.ArrayLike) -> CameraPose:
        """Pose of a body state ``(x, y, z, roll, pitch, yaw)``, the camera mounted by ``R_body_camera``."""
        s = np.asarray(state, dtype=np.float64).reshape(-1)
        if s.shape != (6,) or not np.all(np.isfinite(s)):
            raise InputError(f"a body state is 6 finite numbers (x, y, z, roll, pitch, yaw), got {s.shape}")
        R_world_body = matrix_from_euler(s[3], s[4], s[5])
        return cls(s[:3].copy(), R_world_body @ np.asarray(R_body_camera, dtype=np.float64))

    # -- conversions out --------------------------------------------------------------------------------
    def T_camera_world(self) -> FloatArray:
        """Camera-from-world 4x4 matrix."""
        T = np.eye(4)
        T[:3, :3] = self.R_camera_world
        T[:3, 3] = self.t_camera_world_m
        return T

    def rvec_tvec(self) -> tuple[FloatArray, FloatArray]:
        """OpenCV's camera-from-world rotation vector (rad) and translation (m)."""
        return rotation_vectors(self.R_camera_world[None])[0], self.t_camera_world_m

    def body_state(self, R_body_camera: npt.ArrayLike) -> FloatArray:
        """Body state ``(x, y, z, roll, pitch, yaw)`` of this camera pose with the given mount."""
        R_world_body = self.R_world_camera @ np.asarray(R_body_camera, dtype=np.float64).T
        return np.concatenate([self.p_world_camera_m, euler_from_matrix(R_world_body)])


def parse_pose_numbers(values: Sequence[float]) -> CameraPose:
    """``--initial-pose``: 6 numbers = OpenCV ``rvec`` (rad) then ``tvec`` (m), camera-from-world;
    16 numbers = the camera-from-world 4x4 matrix, row by row."""
    numbers = np.asarray(list(values), dtype=np.float64)
    if numbers.size == 6:
        return CameraPose.from_rvec_tvec(numbers[:3], numbers[3:])
    if numbers.size == 16:
        return CameraPose.from_T_camera_world(numbers.reshape(4, 4))
    raise InputError(
        f"a pose is 6 numbers (rvec rx ry rz, tvec tx ty tz; camera-from-world) or 16 (the 4x4 "
        f"camera-from-world matrix, row-major), got {numbers.size}"
    )


# -- batched SO(3) ----------------------------------------------------------------------------------------
def rotation_matrices(rotvecs: npt.ArrayLike) -> FloatArray:
    """Exponential map (Rodrigues) of rotation vectors (N, 3) -> rotation matrices (N, 3, 3)."""
    v = np.asarray(rotvecs, dtype=np.float64).reshape(-1, 3)
    angle = np.linalg.norm(v, axis=1)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    k = v / safe[:, None]
    K = np.zeros((v.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s = np.where(small, 0.0, np.sin(angle))[:, None, None]
    c = np.where(small, 0.0, 1.0 - np.cos(angle))[:, None, None]
    R = np.eye(3)[None] + s * K + c * (K @ K)
    if small.any():  # first order for tiny angles: I + [v]x
        Vx = np.zeros((int(small.sum()), 3, 3))
        w = v[small]
        Vx[:, 0, 1], Vx[:, 0, 2], Vx[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
        Vx[:, 1, 0], Vx[:, 2, 0], Vx[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
        R[small] = np.eye(3)[None] + Vx
    return np.asarray(R)


def rotation_vectors(R: npt.ArrayLike) -> FloatArray:
    """Logarithmic map of rotation matrices (N, 3, 3) -> rotation vectors (N, 3), angle in [0, pi]."""
    M = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    cos = np.clip((np.trace(M, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)
    sin = np.sin(angle)
    out = np.where(
        (sin > 1e-6)[:, None], axis * (angle / (2.0 * np.where(sin > 1e-6, sin, 1.0)))[:, None], 0.5 * axis
    )
    near_pi = angle > np.pi - 1e-3
    for i in np.flatnonzero(near_pi):  # axis from the symmetric part (rare)
        # (R + R^T) / 2 = cos(t) I + (1 - cos(t)) a a^T: its leading eigenvector is the axis exactly (the
        # antisymmetric sin(t) K part, of order pi - t, is what made the old column pick 1e-5 off)
        _, vectors = np.linalg.eigh((M[i] + M[i].T) / 2.0)
        a = vectors[:, -1]
        if a @ axis[i] < 0.0:
            a = -a
        out[i] = a * angle[i]
    return np.asarray(out)


def world_error_angles(R_true: FloatArray, R_estimated: FloatArray) -> FloatArray:
    """``dtheta`` (N, 3) with ``R_true = Exp(dtheta) R_estimated``: world-frame error angles."""
    return rotation_vectors(np.einsum("nij,nkj->nik", R_true, R_estimated))


def pose_errors(
    p_true_m: FloatArray, R_true: FloatArray, p_estimated_m: FloatArray, R_estimated: FloatArray
) -> FloatArray:
    """(N, 6) errors of estimated poses in the sense of a ``PoseEstimate``'s covariance: the truth about the
    estimate, ``p_true = p_estimated + dp`` and ``R_true = Exp(dtheta) R_estimated``, as ``(dp, dtheta)``.

    Position and angles must be taken in one sense: the covariance's position-rotation correlations change
    sign otherwise: ``bench consistency`` took the localizer's position the other way (``p_estimated -
    p_true``) and so measured the fused covariance's correlations as wrong in sign (a regression test)."""
    return np.hstack([p_true_m - p_estimated_m, world_error_angles(R_true, R_estimated)])


def perturb(R_world_camera: FloatArray, rotvecs_world: FloatArray) -> FloatArray:
    """``Exp(dtheta) R`` for rotations (N, 3, 3) and world-frame rotation vectors (N, 3)."""
    return np.asarray(np.einsum("nij,njk->nik", rotation_matrices(rotvecs_world), R_world_camera))


def rotation_angle_rad(R_a: FloatArray, R_b: FloatArray) -> FloatArray:
    """Angle (rad) of the rotation between ``R_a`` and ``R_b`` (broadcast over leading axes)."""
    trace = np.einsum("...ij,...ij->...", R_a, R_b)
    return np.asarray(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def mean_rotation(R: FloatArray, weights: FloatArray) -> FloatArray:
    """Chordal L2 mean of rotations (N, 3, 3) with weights (N,): the weighted matrix sum projected onto
    SO(3) (SVD); exact for identical rotations, and well defined for any spread below 90 deg."""
    M = np.einsum("n,nij->ij", weights / np.sum(weights), R)
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return np.asarray(U @ D @ Vt)
