"""The one camera model of capataz: intrinsics, lens distortion, projection (OpenCV camera frame).

Frame: x right, y down, z along the optical axis; pixel centres at integer coordinates (OpenCV convention).

Lens models (:class:`DistortionModel`) are exactly OpenCV's, so that calibrations from OpenCV, ROS
``camera_calibration`` and Kalibr apply unchanged:

- ``NONE``: an ideal pinhole.
- ``RADTAN`` (OpenCV's default, ROS ``plumb_bob``): coefficients ``(k1, k2, p1, p2, k3)`` acting on the
  normalised coordinates ``(x, y) = (X / Z, Y / Z)``, with ``r^2 = x^2 + y^2``::

      x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
      y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y

- ``FISHEYE`` (OpenCV's ``cv::fisheye``, ROS ``equidistant``): coefficients ``(k1, k2, k3, k4)``; with
  ``theta = atan(r)``, ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` and
  ``(x_d, y_d) = (theta_d / r) (x, y)``.

Pixels are ``u = fx x_d + cx``, ``v = fy y_d + cy``. Undistortion (pixels -> rays) inverts the lens model by
Newton's method to 1e-12 in normalised coordinates; a lens model that is not invertible over the image (its
radial map folds back inside the frame) is refused when the camera is built.

Default intrinsics (:meth:`CameraModel.default`): a 752x480 Aptina MT9V034 global-shutter sensor (6.0 um
pixels), the sensor of the ETH / Lee et al. 2010 hovering dataset that paper A uses, behind a 2.26 mm lens
giving a 90 deg horizontal field of view: ``fx = fy = 376`` px, ``cx = 375.5``, ``cy = 239.5``, no
distortion. At 1 m above the ground one pixel covers 2.66 mm.

Calibration files (OpenCV YAML, ROS ``camera_info`` YAML) are read by :mod:`common.datasets.calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.types import FloatArray

DEFAULT_WIDTH_PX = 752
DEFAULT_HEIGHT_PX = 480
DEFAULT_HFOV_DEG = 90.0

_NEWTON_ITERATIONS = 30
_NEWTON_TOL = 1e-12


class DistortionModel(Enum):
    """Lens distortion models (OpenCV's; the value is the name used in settings and on the command line)."""

    NONE = "none"
    RADTAN = "radtan"
    FISHEYE = "fisheye"


#: number of coefficients each model takes (RADTAN also accepts 4: k3 = 0).
_N_COEFFS = {DistortionModel.NONE: 0, DistortionModel.RADTAN: 5, DistortionModel.FISHEYE: 4}


@dataclass(frozen=True)
class Distortion:
    """A lens distortion model and its coefficients (see the module docstring for the equations)."""

    model: DistortionModel = DistortionModel.NONE
    coeffs: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        model = DistortionModel(self.model)
        coeffs = tuple(float(c) for c in self.coeffs)
        if model is DistortionModel.RADTAN and len(coeffs) == 4:
            coeffs = (*coeffs, 0.0)
        if model is DistortionModel.NONE and coeffs and not any(coeffs):
            coeffs = ()
        if len(coeffs) != _N_COEFFS[model]:
            raise InputError(
                f"distortion model {model.value!r} takes {_N_COEFFS[model]} coefficients, got {len(coeffs)}"
            )
        if not all(np.isfinite(coeffs)):
            raise InputError(f"distortion coefficients must be finite, got {coeffs}")
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "coeffs", coeffs)

    @property
    def is_identity(self) -> bool:
        """True when the model leaves every point where it is: none, or radtan with all-zero coefficients
        (a fisheye with all-zero coefficients is the ideal equidistant lens, ``theta_d = theta``: not a
        pinhole)."""
        return self.model is DistortionModel.NONE or (
            self.model is DistortionModel.RADTAN and not any(self.coeffs)
        )

    def distort(self, xy: FloatArray) -> FloatArray:
        """Distorted normalised coordinates ``(N, 2)`` of ideal normalised coordinates ``(N, 2)``."""
        if self.is_identity:
            return xy.copy()
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        if self.model is DistortionModel.RADTAN:
            k1, k2, p1, p2, k3 = self.coeffs
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            return np.stack([xd, yd], axis=1)
        k1, k2, k3, k4 = self.coeffs
        r = np.sqrt(r2)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
        return xy * scale[:, None]

    def undistort(self, xy_d: FloatArray) -> FloatArray:
        """Ideal normalised coordinates of distorted ones ``(N, 2)`` (Newton's method on :meth:`distort`).

        Points where Newton does not converge (where the lens model is not invertible) come out NaN.
        """
        if self.is_identity:
            return xy_d.copy()
        xy = xy_d.copy()
        h = 1e-7
        dx, dy = np.array([h, 0.0]), np.array([0.0, h])
        converged = np.zeros(len(xy), dtype=bool)
        for _ in range(_NEWTON_ITERATIONS):
            f = self.distort(xy) - xy_d
            fx = (self.distort(xy + dx) - self.distort(xy - dx)) / (2.0 * h)
            fy = (self.distort(xy + dy) - self.distort(xy - dy)) / (2.0 * h)
            a, b, c, d = fx[:, 0], fy[:, 0], fx[:, 1], fy[:, 1]
            det = a * d - b * c
            det = np.where(np.abs(det) < 1e-15, np.nan, det)
            step = np.stack([(d * f[:, 0] - b * f[:, 1]) / det, (a * f[:, 1] - c * f[:, 0]) / det], axis=1)
            xy = xy - step
            converged = np.nan_to_num(np.abs(step).max(axis=1), nan=np.inf) < _NEWTON_TOL
            if converged.all():
                break
        residual = np.abs(self.distort(xy) - xy_d).max(axis=1)
        ok = np.isfinite(residual) & (residual < 1e-9)
        xy[~ok] = np.nan
        return xy


NO_DISTORTION = Distortion()


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and lens distortion of one camera; pixel centres at integer coordinates (OpenCV)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Distortion = field(default=NO_DISTORTION)

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
        if not isinstance(self.distortion, Distortion):
            raise InputError(f"distortion must be a Distortion, got {type(self.distortion).__name__}")
        if not self.distortion.is_identity:
            check_invertible_over_image(self)

    # ---- construction -------------------------------------------------------------------------------------

    @classmethod
    def default(cls) -> CameraModel:
        """752x480 MT9V034 with a 90 deg horizontal field of view (see the module docstring)."""
        return cls.from_hfov(DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX, DEFAULT_HFOV_DEG)

    @classmethod
    def from_hfov(
        cls, width: int, height: int, hfov_deg: float, distortion: Distortion = NO_DISTORTION
    ) -> CameraModel:
        """Square pixels, principal point at the image centre, the given horizontal FOV (of the pinhole)."""
        if not 0.0 < hfov_deg < 180.0:
            raise InputError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(
            width=width,
            height=height,
            fx=f,
            fy=f,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
            distortion=distortion,
        )

    @classmethod
    def from_K(
        cls, K: npt.ArrayLike, width: int, height: int, distortion: Distortion = NO_DISTORTION
    ) -> CameraModel:
        """Camera from a 3x3 intrinsic matrix (skew must be zero)."""
        K_arr = np.asarray(K, dtype=np.float64)
        if K_arr.shape != (3, 3) or not np.all(np.isfinite(K_arr)):
            raise InputError(f"K must be a finite (3, 3) matrix, got shape {K_arr.shape}")
        if (
            abs(K_arr[0, 1]) > 1e-9
            or np.any(np.abs(K_arr[2] - [0.0, 0.0, 1.0]) > 1e-9)
            or abs(K_arr[1, 0]) > 1e-9
        ):
            raise InputError(f"K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {K_arr.tolist()}")
        return cls(
            width=width,
            height=height,
            fx=float(K_arr[0, 0]),
            fy=float(K_arr[1, 1]),
            cx=float(K_arr[0, 2]),
            cy=float(K_arr[1, 2]),
            distortion=distortion,
        )

    def pinhole(self) -> CameraModel:
        """The same camera without lens distortion (what undistorted pixels live in)."""
        return replace(self, distortion=NO_DISTORTION)

    def scaled(self, factor: float) -> CameraModel:
        """The camera of the image resized by ``factor`` (pixel-centre convention kept)."""
        if not (np.isfinite(factor) and factor > 0.0):
            raise InputError(f"scale factor must be positive, got {factor}")
        w, h = round(self.width * factor), round(self.height * factor)
        return replace(
            self,
            width=w,
            height=h,
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
        )

    # ---- properties ---------------------------------------------------------------------------------------

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
    def is_distorted(self) -> bool:
        """True when the lens model is not an ideal pinhole."""
        return not self.distortion.is_identity

    @property
    def hfov_rad(self) -> float:
        """Horizontal field of view of the pinhole part (edge to edge of the pixel grid)."""
        return float(2.0 * np.arctan((self.width / 2.0) / self.fx))

    def corners_px(self) -> FloatArray:
        """Outer corners of the pixel grid ``(4, 2)``: top-left, top-right, bottom-right, bottom-left."""
        w, h = float(self.width), float(self.height)
        return np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])

    # ---- projection ---------------------------------------------------------------------------------------

    def project(self, points_camera: npt.ArrayLike) -> FloatArray:
        """Pixels ``(N, 2)`` (or ``(2,)``) of camera-frame points ``(N, 3)`` (or ``(3,)``), through the lens.

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
        xy = self.distortion.distort(pts[:, :2] / pts[:, 2:3])
        uv = np.stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy], axis=1)
        return uv[0] if single else uv

    def rays(self, pixels: npt.ArrayLike) -> FloatArray:
        """Camera-frame rays ``(N, 3)`` with z = 1 through pixels ``(N, 2)`` (inverse of :meth:`project`).

        Pixels where the lens model cannot be inverted give NaN rays.
        """
        px = _check_pixels(pixels)
        single = np.ndim(pixels) == 1
        xy = self.distortion.undistort(
            np.stack([(px[:, 0] - self.cx) / self.fx, (px[:, 1] - self.cy) / self.fy], 1)
        )
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        return rays[0] if single else rays

    def undistort_px(self, pixels: npt.ArrayLike) -> FloatArray:
        """Where pixels ``(N, 2)`` of this camera fall in its distortion-free twin (:meth:`pinhole`)."""
        if not self.is_distorted:
            return _check_pixels(pixels).copy()
        rays = np.atleast_2d(self.rays(pixels))
        return np.stack([self.fx * rays[:, 0] + self.cx, self.fy * rays[:, 1] + self.cy], axis=1)

    def distort_px(self, pixels_pinhole: npt.ArrayLike) -> FloatArray:
        """Inverse of :meth:`undistort_px`: pixels of the pinhole twin -> pixels through the lens."""
        px = _check_pixels(pixels_pinhole)
        xy = np.stack([(px[:, 0] - self.cx) / self.fx, (px[:, 1] - self.cy) / self.fy], axis=1)
        xy_d = self.distortion.distort(xy)
        return np.stack([self.fx * xy_d[:, 0] + self.cx, self.fy * xy_d[:, 1] + self.cy], axis=1)


def _check_pixels(pixels: npt.ArrayLike) -> FloatArray:
    px = np.atleast_2d(np.asarray(pixels, dtype=np.float64))
    if px.ndim != 2 or px.shape[1] != 2:
        raise InputError(f"pixels must have shape (N, 2) or (2,), got {np.shape(pixels)}")
    if not np.all(np.isfinite(px)):
        raise InputError("pixels must be finite")
    return px


def check_invertible_over_image(camera: CameraModel, samples: int = 1024) -> None:
    """Raise InputError unless the lens maps (nearly all of) the image's field one-to-one.

    Walks the radial map r -> r_d outwards along the diagonal. A map that folds back (stops increasing) before
    90 % of the farthest corner's distorted radius is refused: most of the frame would have no ray. A fold
    between 90 % and 100 % is accepted (real calibrations, e.g. OpenCV's own sample, extrapolate badly in the
    extreme corners); :meth:`CameraModel.rays` returns NaN for the few corner pixels without a preimage.
    """
    corners = camera.corners_px()
    xy_d = np.stack(
        [(corners[:, 0] - camera.cx) / camera.fx, (corners[:, 1] - camera.cy) / camera.fy], axis=1
    )
    r_d_max = float(np.sqrt((xy_d**2).sum(axis=1)).max())
    direction = np.array([1.0, 1.0]) / np.sqrt(2.0)
    r = np.linspace(0.0, 1.0, samples + 1)[1:]
    previous = 0.0
    name = f"{camera.distortion.model.value} {camera.distortion.coeffs}"
    while True:
        r_dist = np.sqrt((camera.distortion.distort(r[:, None] * direction) ** 2).sum(axis=1))
        reached = np.flatnonzero(r_dist >= r_d_max)
        upto = int(reached[0]) + 1 if len(reached) else len(r_dist)
        steps = np.diff(np.concatenate([[previous], r_dist[:upto]]))
        folds = np.flatnonzero(steps <= 0.0)
        if len(folds):
            peak = float(np.concatenate([[previous], r_dist])[folds[0]])
            if peak >= 0.9 * r_d_max:
                return
            raise InputError(
                f"distortion {name} is not invertible over the {camera.width}x{camera.height} image "
                f"(its radial map folds back at {100.0 * peak / r_d_max:.0f} % of the corner radius)"
            )
        if len(reached):
            return
        if r[-1] > 1e3:
            raise InputError(
                f"distortion {name} never reaches the corners of the {camera.width}x{camera.height} image"
            )
        previous = float(r_dist[-1])
        r = np.linspace(r[-1], 2.0 * r[-1], samples + 1)[1:]
