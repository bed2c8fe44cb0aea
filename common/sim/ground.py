"""Textured ground plane ``z = 0`` and its exact rendering through the plane-induced homography.

The texture is the paper's "large noise image, like a carpet": Gaussian noise with a 1/f amplitude
spectrum (equal variance in every octave, so there is detail at every scale from the texel up to the
texture size), synthesised in the Fourier domain from a seed, hence exactly periodic: the ground is an
endless tiling of it and never runs out. Default: 4096 x 4096 texels of 2.5 mm (a 10.24 m tile), finer than
the 2.66 mm a pixel of the default camera covers at 1 m. The default camera's footprint (2 x 1.28 m per m of
altitude) spans at most 9.5 m along a tile axis at 4 m, so no view up to 4.3 m altitude contains the same
ground twice; above that the far edges of some views repeat.

Rendering maps every pixel to the ground by the exact homography ``H_pixel_ground = K [r1 r2 t]``
(``r1, r2`` the first two columns of ``R_camera_world``, ``t = -R_camera_world p_world_camera``) and samples
the texture with ``cv2.warpPerspective`` (bilinear) from a contiguous (wrapped) crop of the footprint,
which keeps memory access local whatever the yaw. Anti-aliasing: a mip-map pyramid
(``cv2.pyrDown`` on the periodic texture) and trilinear filtering: the level of detail is ``log2`` of the
texels a pixel covers (largest singular value of the homography's Jacobian, the worst of the image centre
and corners), the two bracketing levels are warped and blended. So the image stays band-limited at every
altitude instead of aliasing, and changes smoothly with altitude.

Texture coordinates: level-0 texel ``(col, row)`` lies at world ``x = origin_x_m + col * texel_m``,
``y = origin_y_m + row * texel_m``; level ``L`` texel ``(c, r)`` at level-0 coordinate ``(c 2^L, r 2^L)``
(the centre alignment of ``cv2.pyrDown``).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from common.camera import CameraModel
from common.errors import CapatazError, InputError
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix, matrix_from_euler
from common.types import FloatArray, U8Array

logger = logging.getLogger(__name__)

#: Stream label mixed into the seed so the texture's random numbers differ from the flight's noise.
TEXTURE_STREAM = 0x7E7
#: Bilinear footprint margin around the crop a view is warped from (texels).
CROP_MARGIN_PX = 2
#: Above this many texels the footprint is not cropped (grazing views).
MAX_CROP_TEXELS = 16 * 1024 * 1024
#: Smallest pyramid level kept (px per side).
MIN_LEVEL_SIZE_PX = 32


class GroundViewError(CapatazError):
    """The requested view cannot be rendered (camera below the ground, horizon in view, ...)."""


@dataclass(frozen=True, eq=False)
class GroundTexture:
    """A periodic ground texture and its mip-map pyramid (``levels[0]`` is full resolution, uint8)."""

    seed: int
    texel_m: float
    origin_x_m: float
    origin_y_m: float
    levels: tuple[U8Array, ...]

    @property
    def size_px(self) -> int:
        """Side of the square level-0 texture in texels."""
        return int(self.levels[0].shape[0])

    @property
    def period_m(self) -> float:
        """Side of one tile of the periodic ground (m)."""
        return self.size_px * self.texel_m

    def world_from_texel(self, level: int) -> FloatArray:
        """Homogeneous map (3, 3) from level-``level`` texel coordinates to world ``(x, y, 1)``."""
        s = self.texel_m * float(2**level)
        return np.array([[s, 0.0, self.origin_x_m], [0.0, s, self.origin_y_m], [0.0, 0.0, 1.0]])

    def texel_from_world(self, level: int) -> FloatArray:
        """Inverse of :meth:`world_from_texel`."""
        s = self.texel_m * float(2**level)
        return np.array(
            [[1.0 / s, 0.0, -self.origin_x_m / s], [0.0, 1.0 / s, -self.origin_y_m / s], [0.0, 0.0, 1.0]]
        )


def make_ground_texture(
    seed: int = 0,
    size_px: int = 4096,
    texel_m: float = 0.0025,
    spectral_exponent: float = 1.0,
    contrast_dn: float = 40.0,
) -> GroundTexture:
    """Deterministic multi-scale noise "carpet" (same seed and settings -> identical bytes).

    ``size_px`` (a power of two >= 64) texels of ``texel_m`` metres; amplitude spectrum
    ``1 / f**spectral_exponent``
    (1.0 = equal energy per octave); grey levels ``128 +- contrast_dn`` per standard deviation, clipped to
    0..255. The tile is centred on the world origin. Takes about 1 s for the default 4096 x 4096.
    """
    if size_px < 64 or size_px & (size_px - 1):
        raise InputError(f"size_px must be a power of two >= 64, got {size_px}")
    if not (np.isfinite(texel_m) and texel_m > 0.0):
        raise InputError(f"texel_m must be positive, got {texel_m}")
    if not (np.isfinite(spectral_exponent) and 0.0 <= spectral_exponent <= 3.0):
        raise InputError(f"spectral_exponent must be in [0, 3], got {spectral_exponent}")
    if not (np.isfinite(contrast_dn) and contrast_dn > 0.0):
        raise InputError(f"contrast_dn must be positive, got {contrast_dn}")
    rng = np.random.default_rng([TEXTURE_STREAM, int(seed)])
    n = size_px
    half = n // 2 + 1
    spectrum = rng.standard_normal((n, half), dtype=np.float32) + 1j * rng.standard_normal(
        (n, half), dtype=np.float32
    )
    fy = np.fft.fftfreq(n).astype(np.float32)[:, None]
    fx = np.fft.rfftfreq(n).astype(np.float32)[None, :]
    radius = np.sqrt(fx * fx + fy * fy)
    radius[0, 0] = 1.0
    gain = radius ** np.float32(-spectral_exponent)
    gain[0, 0] = 0.0
    spectrum *= gain
    field = np.fft.irfft2(spectrum, s=(n, n))
    field -= field.mean()
    field *= np.float32(contrast_dn / max(float(field.std()), 1e-12))
    field += np.float32(128.0)
    level0 = np.clip(np.rint(field), 0.0, 255.0).astype(np.uint8)
    texture = ground_texture_from_image(level0, texel_m)
    return GroundTexture(
        seed=int(seed),
        texel_m=texture.texel_m,
        origin_x_m=texture.origin_x_m,
        origin_y_m=texture.origin_y_m,
        levels=texture.levels,
    )


def _pyr_down_periodic(image: U8Array) -> U8Array:
    """``cv2.pyrDown`` of a periodic image, keeping it periodic (dst(i) is centred on src(2 i))."""
    pad = 4
    padded = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_WRAP)
    small = cv2.pyrDown(padded)
    h, w = image.shape[0] // 2, image.shape[1] // 2
    return np.ascontiguousarray(small[pad // 2 : pad // 2 + h, pad // 2 : pad // 2 + w])


def _periodic_segments(start: int, length: int, period: int) -> list[tuple[int, int]]:
    """Split ``[start, start + length)`` (mod ``period``) into contiguous ``(begin, end)`` pieces."""
    pieces = []
    position = start % period
    left = length
    while left > 0:
        take = min(left, period - position)
        pieces.append((position, position + take))
        left -= take
        position = 0
    return pieces


def _crop_periodic(image: U8Array, x0: int, y0: int, width: int, height: int) -> U8Array:
    """Contiguous ``(height, width)`` window of a periodic image starting at column ``x0``, row ``y0``."""
    n_rows, n_cols = image.shape
    row_pieces = _periodic_segments(y0, height, n_rows)
    col_pieces = _periodic_segments(x0, width, n_cols)
    if len(row_pieces) == 1 and len(col_pieces) == 1:
        (r0, r1), (c0, c1) = row_pieces[0], col_pieces[0]
        return np.ascontiguousarray(image[r0:r1, c0:c1])
    out = np.empty((height, width), dtype=image.dtype)
    row = 0
    for r0, r1 in row_pieces:
        col = 0
        for c0, c1 in col_pieces:
            out[row : row + r1 - r0, col : col + c1 - c0] = image[r0:r1, c0:c1]
            col += c1 - c0
        row += r1 - r0
    return out


def check_camera_pose(
    R_world_camera: npt.ArrayLike, p_world_camera_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Validated ``(R_world_camera (3, 3), p_world_camera_m (3,))`` or InputError."""
    R = check_rotation_matrix(R_world_camera, "R_world_camera")
    if R.shape != (3, 3):
        raise InputError(f"R_world_camera must have shape (3, 3), got {R.shape}")
    p = np.asarray(p_world_camera_m, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InputError(f"p_world_camera_m must be a finite (3,) vector, got shape {p.shape}")
    return R, p


def ground_homography(
    camera: CameraModel, R_world_camera: npt.ArrayLike, p_world_camera_m: npt.ArrayLike
) -> FloatArray:
    """Plane-induced homography ``H_pixel_ground`` (3, 3): world ground ``(x, y, 1)`` -> pixel (homogeneous).

    ``H = K [r1 r2 t]`` with ``r1, r2`` the first two columns of ``R_camera_world`` and
    ``t = -R_camera_world p_world_camera``. Raises GroundViewError when the camera is not above the ground
    or a corner of the image does not see the ground (horizon in view).
    """
    R, p = check_camera_pose(R_world_camera, p_world_camera_m)
    if p[2] <= 0.0:
        raise GroundViewError(f"the camera must be above the ground (z > 0), got z = {p[2]:.4g} m")
    corner_rays_world = camera.rays(camera.corners_px()) @ R.T
    if np.any(corner_rays_world[:, 2] >= -1e-6):
        raise GroundViewError("an image corner does not see the ground (the horizon is in view)")
    R_camera_world = R.T
    t = -R_camera_world @ p
    M = np.column_stack([R_camera_world[:, 0], R_camera_world[:, 1], t])
    return np.asarray(camera.K @ M, dtype=np.float64)


def homography_between_views(
    camera: CameraModel,
    R_world_camera_a: npt.ArrayLike,
    p_world_camera_a_m: npt.ArrayLike,
    R_world_camera_b: npt.ArrayLike,
    p_world_camera_b_m: npt.ArrayLike,
) -> FloatArray:
    """Ground-induced homography ``H_b_a`` (3, 3, ``H[2, 2] = 1``): pixel in view a -> pixel in view b."""
    H_a = ground_homography(camera, R_world_camera_a, p_world_camera_a_m)
    H_b = ground_homography(camera, R_world_camera_b, p_world_camera_b_m)
    H = H_b @ np.linalg.inv(H_a)
    return np.asarray(H / H[2, 2], dtype=np.float64)


def _max_texels_per_pixel(H_texel_pixel: FloatArray, points_px: FloatArray) -> float:
    """Largest singular value of the Jacobian of ``H_texel_pixel`` over ``points_px`` (N, 2)."""
    worst = 0.0
    A = H_texel_pixel[:2, :2]
    b = H_texel_pixel[:2, 2]
    c = H_texel_pixel[2, :2]
    d = H_texel_pixel[2, 2]
    for x in points_px:
        w = float(c @ x + d)
        mapped = (A @ x + b) / w
        J = (A - np.outer(mapped, c)) / w
        worst = max(worst, float(np.linalg.svd(J, compute_uv=False)[0]))
    return worst


def render_ground_view(
    texture: GroundTexture,
    camera: CameraModel,
    R_world_camera: npt.ArrayLike,
    p_world_camera_m: npt.ArrayLike,
    lod_bias: float = 0.0,
) -> U8Array:
    """Exact view ``(H, W) uint8`` of the textured ground from a camera pose, anti-aliased (mip-mapped).

    ``R_world_camera`` rotates OpenCV-camera vectors into the ENU world; ``p_world_camera_m`` is the centre of
    projection. ``lod_bias`` > 0 blurs more (sharper aliasing-free margin), < 0 sharper. Noise-free: apply an
    :class:`~common.sim.sensors.ImageDegradation` for sensor effects. A distorted ``camera`` is a
    :class:`GroundViewError` (a homography draws a pinhole only; :mod:`common.sim.field` draws any lens).
    """
    if camera.is_distorted:
        # a homography draws a pinhole only: a distorted lens's frames would not be what its model says
        raise GroundViewError(
            f"the ground view draws pinhole cameras only, got a {camera.distortion.model.value} lens: "
            "render it through common.sim.field (field_flight, render_lens_view)"
        )
    H_pixel_ground = ground_homography(camera, R_world_camera, p_world_camera_m)
    H_ground_pixel = np.linalg.inv(H_pixel_ground)
    points = np.vstack([camera.corners_px(), [[camera.cx, camera.cy]]])
    scale0 = _max_texels_per_pixel(texture.texel_from_world(0) @ H_ground_pixel, points)
    lod = float(np.clip(np.log2(scale0) + lod_bias, 0.0, len(texture.levels) - 1))
    level_lo = int(np.floor(lod))
    frac = lod - level_lo
    if level_lo >= len(texture.levels) - 1:
        level_lo, frac = len(texture.levels) - 1, 0.0
    size = (int(camera.width), int(camera.height))
    centre_ground = H_ground_pixel @ np.array([camera.cx, camera.cy, 1.0])
    centre_ground = centre_ground / centre_ground[2]

    corners_px = np.column_stack([camera.corners_px(), np.ones(4)])

    def warp(level: int) -> U8Array:
        H_texel_pixel = texture.texel_from_world(level) @ H_ground_pixel
        corners = corners_px @ H_texel_pixel.T
        corners = corners[:, :2] / corners[:, 2:]
        x0, y0 = np.floor(corners.min(axis=0)).astype(np.int64) - CROP_MARGIN_PX
        x1, y1 = np.ceil(corners.max(axis=0)).astype(np.int64) + CROP_MARGIN_PX + 1
        if (x1 - x0) * (y1 - y0) <= MAX_CROP_TEXELS:
            # Warp from a contiguous crop of the footprint: cache-friendly whatever the yaw (5-10x faster
            # than sampling the whole tile along its columns) and small 16-bit coordinates for cv2.
            source = _crop_periodic(texture.levels[level], int(x0), int(y0), int(x1 - x0), int(y1 - y0))
            T = np.array([[1.0, 0.0, -float(x0)], [0.0, 1.0, -float(y0)], [0.0, 0.0, 1.0]])
            border = cv2.BORDER_REPLICATE
        else:  # huge footprint (grazing view): sample the periodic tile directly, shifted by whole tiles
            source = texture.levels[level]
            period = source.shape[0]
            centre = texture.texel_from_world(level) @ centre_ground
            shift = np.floor(centre[:2] / period) * period
            T = np.array([[1.0, 0.0, -shift[0]], [0.0, 1.0, -shift[1]], [0.0, 0.0, 1.0]])
            border = cv2.BORDER_WRAP
        warped = cv2.warpPerspective(
            source, T @ H_texel_pixel, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=border
        )
        return np.asarray(warped, dtype=np.uint8)

    image = warp(level_lo)
    if frac > 1e-3:
        upper = warp(level_lo + 1)
        image = np.asarray(cv2.addWeighted(image, 1.0 - frac, upper, frac, 0.0), dtype=np.uint8)
    return np.asarray(image).astype(np.uint8, copy=False)


def camera_pose_from_body(
    R_world_body: npt.ArrayLike,
    p_world_body_m: npt.ArrayLike,
    R_body_camera: npt.ArrayLike,
    p_body_camera_m: npt.ArrayLike = (0.0, 0.0, 0.0),
) -> tuple[FloatArray, FloatArray]:
    """Camera pose ``(R_world_camera, p_world_camera_m)`` from the body pose and the camera mounting."""
    R_wb = np.asarray(R_world_body, dtype=np.float64)
    R_bc = np.asarray(R_body_camera, dtype=np.float64)
    p_wb = np.asarray(p_world_body_m, dtype=np.float64)
    p_bc = np.asarray(p_body_camera_m, dtype=np.float64)
    return R_wb @ R_bc, p_wb + R_wb @ p_bc


def render_pair(
    texture: GroundTexture,
    camera: CameraModel,
    pose_a: tuple[npt.ArrayLike, npt.ArrayLike],
    pose_b: tuple[npt.ArrayLike, npt.ArrayLike],
) -> tuple[U8Array, U8Array, FloatArray]:
    """Two noise-free views and their true ground homography ``H_b_a`` (pixel a -> pixel b).

    Each pose is ``(R_world_camera, p_world_camera_m)``.
    """
    image_a = render_ground_view(texture, camera, pose_a[0], pose_a[1])
    image_b = render_ground_view(texture, camera, pose_b[0], pose_b[1])
    H_b_a = homography_between_views(camera, pose_a[0], pose_a[1], pose_b[0], pose_b[1])
    return image_a, image_b, H_b_a


def nadir_camera_pose(
    x_m: float, y_m: float, altitude_m: float, yaw_rad: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Pose ``(R_world_camera, p_world_camera_m)`` of a camera looking straight down from a level body.

    The body has the given yaw (ZYX, CCW from above) and the camera is mounted as ``R_BODY_CAMERA_DOWN``.
    Handy for yaw tests: two nadir views at the same place whose yaws differ by ``dyaw`` are related by the
    pixel homography ``H_b_a`` = a rotation about the principal point by ``+dyaw`` in (u right, v down)
    coordinates, i.e. ``dyaw = atan2(H_b_a[1, 0], H_b_a[0, 0])``.
    """
    R_world_body = matrix_from_euler(0.0, 0.0, yaw_rad)
    return R_world_body @ R_BODY_CAMERA_DOWN, np.array([x_m, y_m, altitude_m], dtype=np.float64)


def ground_texture_from_image(
    image: npt.ArrayLike, texel_m: float, origin_x_m: float | None = None, origin_y_m: float | None = None
) -> GroundTexture:
    """A :class:`GroundTexture` from a square power-of-two uint8 image (treated as periodic), e.g. a test
    pattern. The tile is centred on the world origin unless an origin is given."""
    level0 = np.asarray(image)
    n = level0.shape[0] if level0.ndim == 2 else 0
    if level0.dtype != np.uint8 or level0.ndim != 2 or level0.shape[1] != n or n < 64 or n & (n - 1):
        raise InputError(
            f"image must be a square power-of-two (>= 64) uint8 array, got {level0.dtype} {level0.shape}"
        )
    if not (np.isfinite(texel_m) and texel_m > 0.0):
        raise InputError(f"texel_m must be positive, got {texel_m}")
    levels = [np.ascontiguousarray(level0).copy()]
    while levels[-1].shape[0] // 2 >= MIN_LEVEL_SIZE_PX:
        levels.append(_pyr_down_periodic(levels[-1]))
    for level in levels:
        level.setflags(write=False)
    origin = -0.5 * n * texel_m
    return GroundTexture(
        seed=-1,
        texel_m=float(texel_m),
        origin_x_m=origin if origin_x_m is None else float(origin_x_m),
        origin_y_m=origin if origin_y_m is None else float(origin_y_m),
        levels=tuple(levels),
    )
