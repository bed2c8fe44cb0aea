"""Pinhole camera model of the simulator (OpenCV camera frame: x right, y down, z optical axis).

Default intrinsics (:meth:`PinholeCamera.default`): a 752x480 Aptina MT9V034 global-shutter sensor
(6.0 um square pixels, 4.51 x 2.88 mm active area), the sensor of the ETH / Lee et al. 2010 hovering
dataset that paper A uses, behind a 2.26 mm lens giving a 90 deg horizontal field of view:

- ``fx = fy = 376.0`` px (= (752 / 2) / tan(45 deg), i.e. 2.256 mm / 6 um), square pixels, no skew;
- ``cx = 375.5``, ``cy = 239.5`` (the exact image centre in the pixel-centre-at-integer convention);
- vertical field of view 2 * atan(240 / 376) = 65.1 deg; no lens distortion (the frames are rendered
  through an ideal pinhole).

At 1 m above the ground one pixel covers 1 / 376 m = 2.66 mm of ground, at 5 m 13.3 mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError

FloatArray = npt.NDArray[np.float64]

DEFAULT_WIDTH_PX = 752
DEFAULT_HEIGHT_PX = 480
DEFAULT_HFOV_DEG = 90.0


@dataclass(frozen=True)
class PinholeCamera:
    """Ideal pinhole camera; pixel centres at integer coordinates (OpenCV convention)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if int(self.width) != self.width or int(self.height) != self.height:
            raise InputError(f"camera size must be integral, got {self.width}x{self.height}")
        if self.width < 2 or self.height < 2:
            raise InputError(f"camera size must be at least 2x2 px, got {self.width}x{self.height}")
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(v) for v in values):
            raise InputError(f"camera intrinsics must be finite, got {values}")
        if self.fx <= 0.0 or self.fy <= 0.0:
            raise InputError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def default(cls) -> PinholeCamera:
        """752x480 MT9V034 with a 90 deg horizontal field of view (see the module docstring)."""
        return cls.from_hfov(DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX, DEFAULT_HFOV_DEG)

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> PinholeCamera:
        """Square-pixel camera with the principal point at the image centre and the given horizontal FOV."""
        if not 0.0 < hfov_deg < 180.0:
            raise InputError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0)

    @property
    def K(self) -> FloatArray:
        """Intrinsic matrix (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_inv(self) -> FloatArray:
        """Inverse intrinsic matrix (3, 3)."""
        return np.array(
            [
                [1.0 / self.fx, 0.0, -self.cx / self.fx],
                [0.0, 1.0 / self.fy, -self.cy / self.fy],
                [0.0, 0.0, 1.0],
            ]
        )

    @property
    def shape(self) -> tuple[int, int]:
        """Image shape ``(height, width)`` as numpy uses it."""
        return (int(self.height), int(self.width))

    @property
    def hfov_rad(self) -> float:
        """Horizontal field of view (edge to edge of the pixel grid)."""
        return float(2.0 * np.arctan((self.width / 2.0) / self.fx))

    def project(self, points_camera: npt.ArrayLike) -> FloatArray:
        """Pixels ``(N, 2)`` of points ``(N, 3)`` (or one point ``(3,)``) in the camera frame.

        Points must lie in front of the camera (z > 0); raises InputError otherwise.
        """
        pts = np.asarray(points_camera, dtype=np.float64)
        single = pts.ndim == 1
        pts = np.atleast_2d(pts)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"points_camera must have shape (N, 3) or (3,), got {np.shape(points_camera)}")
        if not np.all(np.isfinite(pts)):
            raise InputError("points_camera must be finite")
        if np.any(pts[:, 2] <= 0.0):
            raise InputError("points_camera must lie in front of the camera (z > 0)")
        u = self.fx * pts[:, 0] / pts[:, 2] + self.cx
        v = self.fy * pts[:, 1] / pts[:, 2] + self.cy
        uv = np.stack([u, v], axis=1)
        return uv[0] if single else uv

    def rays(self, pixels: npt.ArrayLike) -> FloatArray:
        """Camera-frame rays ``(N, 3)`` with z = 1 through pixels ``(N, 2)`` (inverse of :meth:`project`)."""
        px = np.asarray(pixels, dtype=np.float64)
        single = px.ndim == 1
        px = np.atleast_2d(px)
        if px.ndim != 2 or px.shape[1] != 2:
            raise InputError(f"pixels must have shape (N, 2) or (2,), got {np.shape(pixels)}")
        x = (px[:, 0] - self.cx) / self.fx
        y = (px[:, 1] - self.cy) / self.fy
        rays = np.stack([x, y, np.ones_like(x)], axis=1)
        return rays[0] if single else rays

    def corners_px(self) -> FloatArray:
        """Outer corners of the pixel grid ``(4, 2)``: top-left, top-right, bottom-right, bottom-left."""
        w, h = float(self.width), float(self.height)
        return np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
