"""Orthogonal rectification of paper C section III-C (Figs. 5-9).

With the EKF's roll and pitch, each frame is warped to the view of a camera at the same centre whose
optical axis is vertical (pointing down) and whose heading is the body's: the "rectified camera",
``R_world_rcam = Rz(yaw) @ R_BODY_CAMERA_DOWN``. The paper builds the warp by projecting the image corners
onto the ground from ``c0 = [0 0 h]`` with the true attitude (a trapezoid) and re-projecting them with the
vertical camera (a rectangle). For a common centre this is the rotation-only homography
``H = K R_rcam_cam K^-1`` whatever ``h`` is (the ground plane cancels), which is what
:func:`rectifying_homography` returns; the test suite checks the equivalence with the corner construction.
The altitude is still needed, for the metric scale of the visual odometry.

The valid region (the warped image outline, Fig. 7) is returned as a mask; the visual odometry keeps only
features inside the masks of both frames of a pair (their overlap, Fig. 9).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.errors import CapatazError
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix, matrix_from_euler
from common.images import check_grey_image
from common.types import FloatArray, U8Array


class RectificationError(CapatazError):
    """The frame cannot be rectified (tilt too large for the rectified view to see the image)."""


@dataclass(frozen=True)
class RectifiedFrame:
    """A frame seen by the rectified (vertical) camera, with the mask of pixels that came from the image."""

    image: U8Array
    valid_mask: U8Array
    H_rect_orig: FloatArray
    R_rcam_cam: FloatArray


def rectifying_rotation(roll_rad: float, pitch_rad: float, R_body_camera: npt.ArrayLike) -> FloatArray:
    """``R_rcam_cam``: camera-frame vectors to the rectified (level, vertical-axis) camera frame.

    ``R_world_cam = Rz Ry Rx R_body_camera`` and ``R_world_rcam = Rz R_BODY_CAMERA_DOWN``, so
    ``R_rcam_cam = R_BODY_CAMERA_DOWN^T Ry(pitch) Rx(roll) R_body_camera`` (independent of yaw).
    """
    R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
    R_tilt = matrix_from_euler(roll_rad, pitch_rad, 0.0)
    return np.asarray(R_BODY_CAMERA_DOWN.T @ R_tilt @ R_bc, dtype=np.float64)


def rectifying_homography(K: npt.ArrayLike, R_rcam_cam: npt.ArrayLike) -> FloatArray:
    """Pixel map original -> rectified for a common centre: ``H = K R_rcam_cam K^-1`` (paper C III-C)."""
    Km = np.asarray(K, dtype=np.float64)
    H = Km @ np.asarray(R_rcam_cam, dtype=np.float64) @ np.linalg.inv(Km)
    return np.asarray(H / H[2, 2], dtype=np.float64)


def rectify_frame(
    image: npt.ArrayLike,
    K: npt.ArrayLike,
    roll_rad: float,
    pitch_rad: float,
    R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN,
    border_px: int = 2,
    interpolation: int = cv2.INTER_LINEAR,
) -> RectifiedFrame:
    """Warp ``image`` to the rectified camera (same size and intrinsics) and mask its valid region.

    The mask is the warped outline of the original image shrunk by ``border_px`` (the interpolation border).
    """
    img = check_grey_image(image, "image", min_side_px=8)
    R_rcam_cam = rectifying_rotation(roll_rad, pitch_rad, R_body_camera)
    H = rectifying_homography(K, R_rcam_cam)
    h_px, w_px = img.shape
    corners = np.array(
        [[border_px, border_px], [w_px - 1 - border_px, border_px],
         [w_px - 1 - border_px, h_px - 1 - border_px], [border_px, h_px - 1 - border_px]],
        dtype=np.float64,
    )  # fmt: skip
    mapped = np.c_[corners, np.ones(4)] @ H.T
    if np.any(mapped[:, 2] <= 1e-9):
        raise RectificationError(
            f"tilt too large to rectify (roll {roll_rad:.3f}, pitch {pitch_rad:.3f} rad)"
        )
    polygon = mapped[:, :2] / mapped[:, 2:3]
    rectified = cv2.warpPerspective(img, H, (w_px, h_px), flags=interpolation, borderValue=0)
    mask = np.zeros((h_px, w_px), dtype=np.uint8)
    cv2.fillConvexPoly(mask, np.round(polygon * 16.0).astype(np.int32), 255, lineType=cv2.LINE_8, shift=4)
    return RectifiedFrame(
        image=np.asarray(rectified, dtype=np.uint8), valid_mask=mask, H_rect_orig=H, R_rcam_cam=R_rcam_cam
    )


def ground_corners(
    K: npt.ArrayLike, R_world_camera: npt.ArrayLike, altitude_m: float, corners_px: npt.ArrayLike
) -> FloatArray:
    """Ground points ``(N, 2)`` seen at ``corners_px`` from a camera at ``[0 0 altitude]`` (Fig. 5)."""
    Km = np.asarray(K, dtype=np.float64)
    R = np.asarray(R_world_camera, dtype=np.float64)
    px = np.asarray(corners_px, dtype=np.float64)
    rays_cam = np.c_[px, np.ones(len(px))] @ np.linalg.inv(Km).T
    rays_world = rays_cam @ R.T
    if np.any(rays_world[:, 2] >= 0.0):
        raise RectificationError("a corner ray does not hit the ground")
    scale = -altitude_m / rays_world[:, 2]
    return np.asarray(rays_world[:, :2] * scale[:, None], dtype=np.float64)
