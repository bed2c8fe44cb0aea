"""Homography decompositions of the visual odometry (paper C Algorithm 2): the physically valid solution of
``cv2.decomposeHomographyMat``, the known-normal decomposition, and the similarity of two level views."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.types import FloatArray


class VoError(CapatazError):
    """A pair of frames gave no usable motion (too few features, tracks or inliers, no valid solution)."""


def choose_decomposition(
    rotations: Sequence[npt.ArrayLike],
    translations: Sequence[npt.ArrayLike],
    normals: Sequence[npt.ArrayLike],
    K: FloatArray,
    points_km1_px: FloatArray,
    points_k_px: FloatArray,
    expected_normal: FloatArray,
) -> int:
    """Index of the physically valid solution of ``cv2.decomposeHomographyMat``.

    Keeps the solutions for which every reference point is in front of both cameras
    (``cv2.filterHomographyDecompByVisibleRefpoints`` on normalised coordinates), then the one whose
    plane normal is closest to ``expected_normal`` (the camera's down axis for a downward camera).
    When the translation is too small for the normal to be observable, the one with the smallest translation.
    """
    candidates = list(range(len(rotations)))
    K_inv = np.linalg.inv(K)
    m0 = (points_km1_px @ K_inv[:2, :2].T + K_inv[:2, 2]).astype(np.float32).reshape(-1, 1, 2)
    m1 = (points_k_px @ K_inv[:2, :2].T + K_inv[:2, 2]).astype(np.float32).reshape(-1, 1, 2)
    visible = cv2.filterHomographyDecompByVisibleRefpoints(
        [np.asarray(r, dtype=np.float64) for r in rotations],
        [np.asarray(n, dtype=np.float64) for n in normals],
        m0,
        m1,
    )
    if visible is not None and len(visible) > 0:
        candidates = [int(i) for i in np.asarray(visible).ravel()]
    scores = [float(np.asarray(normals[i]).ravel() @ expected_normal) for i in candidates]
    best = int(np.argmax(scores))
    if scores[best] > 0.0:
        return candidates[best]
    # Without translation the plane normal is unobservable (H is a pure rotation): every solution has the
    # same R and t ~ 0, so the one with the smallest translation is as good as any.
    norms = [float(np.linalg.norm(translations[i])) for i in candidates]
    smallest = int(np.argmin(norms))
    if norms[smallest] > 1e-3:
        raise VoError("no homography decomposition has its plane normal towards the ground")
    return candidates[smallest]


def calibrated_homography(H_px: npt.ArrayLike, K: npt.ArrayLike) -> FloatArray:
    """``K^-1 H K`` scaled so that its middle singular value is 1 and its determinant positive (the
    normalisation under which ``H = R + t n^T / d``)."""
    Km = np.asarray(K, dtype=np.float64)
    Hc = np.linalg.inv(Km) @ np.asarray(H_px, dtype=np.float64) @ Km
    sigma = np.linalg.svd(Hc, compute_uv=False)
    Hc = Hc / sigma[1]
    if np.linalg.det(Hc) < 0.0:
        Hc = -Hc
    return np.asarray(Hc, dtype=np.float64)


def decompose_with_known_normal(Hc: npt.ArrayLike, normal: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``R, T/d`` of a calibrated homography ``Hc = R + (T/d) n^T`` whose plane normal ``n`` is known.

    ``Hc (I - n n^T) = R (I - n n^T)`` fixes ``R`` (orthogonal Procrustes on the plane directions), then
    ``T/d = (Hc - R) n``. Used for the near-pure rotations that ``cv2.decomposeHomographyMat`` does not split.
    """
    H = np.asarray(Hc, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    P = np.eye(3) - np.outer(n, n)
    # R = argmin |R P - H P| over rotations = U diag(1, 1, det(U V^T)) V^T with U S V^T = H P (rank 2)
    U, _, Vt = np.linalg.svd(H @ P)
    D = np.diag([1.0, 1.0, float(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return np.asarray(R, dtype=np.float64), np.asarray((H - R) @ n, dtype=np.float64)


def level_motion_from_matches(
    points_km1_px: npt.ArrayLike, points_k_px: npt.ArrayLike, K: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """``R_k_km1 = Rz(dpsi)`` and ``T/d`` between two level (rectified) views of the ground, by least squares.

    For level cameras the plane normal is the optical axis ``e3`` and the rotation is about it, so the
    calibrated homography ``R + (T/d) e3^T`` maps normalised points ``m -> (R2 m + t_xy) / (1 + t_z)``: a 2-D
    similarity with scale ``s = 1 / (1 + t_z)`` and shift ``b = t_xy / (1 + t_z)``. Closed-form
    (Umeyama) fit on the matches; ``t_z = 1/s - 1``, ``t_xy = b / s``.
    """
    Km = np.asarray(K, dtype=np.float64)
    K_inv = np.linalg.inv(Km)
    a = np.asarray(points_km1_px, dtype=np.float64) @ K_inv[:2, :2].T + K_inv[:2, 2]
    b = np.asarray(points_k_px, dtype=np.float64) @ K_inv[:2, :2].T + K_inv[:2, 2]
    if len(a) < 2:
        raise VoError("a level-motion fit needs at least two matches")
    mean_a = a.mean(axis=0)
    mean_b = b.mean(axis=0)
    a0 = a - mean_a
    b0 = b - mean_b
    var_a = float(np.sum(a0 * a0))
    if var_a <= 1e-18:
        raise VoError("matches are degenerate (all at one point)")
    cross = b0.T @ a0  # sum b0 a0^T
    # rotation angle maximising trace(R^T cross), scale = |.| / var_a
    c = cross[0, 0] + cross[1, 1]
    s_ = cross[1, 0] - cross[0, 1]
    angle = math.atan2(s_, c)
    scale = math.hypot(c, s_) / var_a
    ca, sa = math.cos(angle), math.sin(angle)
    R2 = np.array([[ca, -sa], [sa, ca]])
    shift = mean_b - scale * (R2 @ mean_a)
    t_over_d = np.array([shift[0] / scale, shift[1] / scale, 1.0 / scale - 1.0])
    R = np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])
    return R, t_over_d


def rotation_about_optical_axis(R_k_km1: npt.ArrayLike) -> FloatArray:
    """``Rz(angle)``: the in-plane (about the optical axis, the yaw of a level camera) part of a rotation."""
    R = np.asarray(R_k_km1, dtype=np.float64)
    angle = math.atan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1])
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
