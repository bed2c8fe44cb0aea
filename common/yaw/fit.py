"""Robust fit of the correspondences patch centre -> centre + shift, and the rotation it implies."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.types import BoolArray, FloatArray
from common.yaw.settings import FitModel, YawSettings


@dataclass(frozen=True, eq=False)
class ModelFit:
    """A robust fit: ``homography`` (3, 3) maps frame k-1 pixels to frame k pixels.

    ``ok`` is False when there were too few correspondences or the fit failed (then the homography is
    the identity); ``inliers`` (n,) is over the correspondences given, ``inlier_count`` how many they are;
    ``residual_px`` is the median transfer error of the inliers.
    """

    ok: bool
    homography: FloatArray
    inliers: BoolArray
    residual_px: float
    inlier_count: int = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "inlier_count", int(np.count_nonzero(self.inliers)))


def _failed(n: int) -> ModelFit:
    return ModelFit(ok=False, homography=np.eye(3), inliers=np.zeros(n, dtype=np.bool_), residual_px=math.inf)


def transfer_error_px(homography: FloatArray, src_px: FloatArray, dst_px: FloatArray) -> FloatArray:
    """|H src - dst| per correspondence (n,), pixels."""
    ones = np.ones((src_px.shape[0], 1))
    mapped = np.hstack([src_px, ones]) @ homography.T
    with np.errstate(divide="ignore", invalid="ignore"):
        projected = mapped[:, :2] / mapped[:, 2:3]
    return np.asarray(np.linalg.norm(projected - dst_px, axis=1), dtype=np.float64)


def fit_correspondences(src_px: npt.ArrayLike, dst_px: npt.ArrayLike, settings: YawSettings) -> ModelFit:
    """RANSAC fit (paper A: "RANSAC ... fit the homography") of src -> dst, then a least-squares refit.

    ``FitModel.SIMILARITY`` uses ``cv2.estimateAffinePartial2D`` (rotation, scale, translation),
    ``FitModel.HOMOGRAPHY`` uses ``cv2.findHomography``; both are deterministic for given inputs.
    """
    src = np.asarray(src_px, dtype=np.float64)
    dst = np.asarray(dst_px, dtype=np.float64)
    if src.ndim != 2 or src.shape[1:] != (2,) or dst.shape != src.shape:
        raise InputError(f"src and dst must both have shape (n, 2), got {src.shape} and {dst.shape}")
    n = src.shape[0]
    needed = max(settings.min_inliers, 4 if settings.fit_model is FitModel.HOMOGRAPHY else 3)
    if n < needed or not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        return _failed(n)
    if settings.fit_model is FitModel.SIMILARITY:
        matrix, mask = cv2.estimateAffinePartial2D(
            src,
            dst,
            method=cv2.RANSAC,
            ransacReprojThreshold=settings.ransac_threshold_px,
            maxIters=settings.ransac_max_iters,
            confidence=0.999,
            refineIters=20,
        )
        if matrix is None:
            return _failed(n)
        homography = np.vstack([matrix, [0.0, 0.0, 1.0]])
    else:
        homography, mask = cv2.findHomography(
            src,
            dst,
            cv2.RANSAC,
            settings.ransac_threshold_px,
            maxIters=settings.ransac_max_iters,
            confidence=0.999,
        )
        if homography is None:
            return _failed(n)
        inl = mask.ravel().astype(bool)
        if inl.sum() >= 4:
            refined, _ = cv2.findHomography(src[inl], dst[inl], 0)
            if refined is not None:
                homography = refined
    errors = transfer_error_px(homography, src, dst)
    inliers = errors <= settings.ransac_threshold_px
    count = int(np.count_nonzero(inliers))
    if count < needed:
        return ModelFit(ok=False, homography=np.eye(3), inliers=inliers, residual_px=math.inf)
    residual = float(np.median(errors[inliers]))
    return ModelFit(
        ok=True, homography=np.asarray(homography, dtype=np.float64), inliers=inliers, residual_px=residual
    )


def homography_jacobian(homography: npt.ArrayLike, at_px: npt.ArrayLike) -> FloatArray:
    """The 2x2 Jacobian of the homography's pixel map at the point ``at_px`` [x, y]."""
    H = np.asarray(homography, dtype=np.float64)
    x, y = (float(v) for v in np.asarray(at_px, dtype=np.float64).ravel()[:2])
    u, v, w = H @ np.array([x, y, 1.0])
    return np.array(
        [
            [(H[0, 0] * w - u * H[2, 0]) / w**2, (H[0, 1] * w - u * H[2, 1]) / w**2],
            [(H[1, 0] * w - v * H[2, 0]) / w**2, (H[1, 1] * w - v * H[2, 1]) / w**2],
        ]
    )


def rotation_of_homography_rad(homography: npt.ArrayLike, at_px: npt.ArrayLike) -> float:
    """In-plane rotation (rad) of a homography at a point: the rotation closest to its local Jacobian.

    Paper A's psi from ``H = [[Rz, t], [0, 1]]``: for a similarity this is atan2(H10, H00); for a general
    homography it is the angle of the closest rotation (Frobenius) to the Jacobian at ``at_px``, i.e.
    atan2(J10 - J01, J00 + J11). Image axes x right, y down; positive = the content turns from +x to +y.
    """
    J = homography_jacobian(homography, at_px)
    return math.atan2(J[1, 0] - J[0, 1], J[0, 0] + J[1, 1])


def shift_of_homography_px(homography: npt.ArrayLike, at_px: npt.ArrayLike) -> float:
    """How far a homography moves a point (px): ``|H(p) - p|``, infinite when it maps ``p`` to infinity."""
    H = np.asarray(homography, dtype=np.float64)
    x, y = (float(v) for v in np.asarray(at_px, dtype=np.float64).ravel()[:2])
    u, v, w = H @ np.array([x, y, 1.0])
    if not abs(w) > 1e-12:
        return math.inf
    return math.hypot(u / w - x, v / w - y)


def scale_of_homography(homography: npt.ArrayLike, at_px: npt.ArrayLike) -> float:
    """Local isotropic scale (sqrt |det J|) of a homography at a point."""
    return math.sqrt(abs(float(np.linalg.det(homography_jacobian(homography, at_px)))))
