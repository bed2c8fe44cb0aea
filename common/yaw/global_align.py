"""Coarse global rotation + scale + translation of a whole frame pair (Fourier-Mellin / log-polar).

Used to pre-align a pair whose rotation is far beyond what per-patch translations can follow
(fast spins, dropped frames, the Oxford boat pair's -14 deg with 0.885 zoom).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from common.images import check_grey_image
from common.types import Float32Array, FloatArray, U8Array
from common.yaw.settings import YawSettings


@dataclass(frozen=True, eq=False)
class GlobalAlignment:
    """A similarity ``matrix`` (3, 3) mapping frame-a pixels to frame-b pixels, and its parameters.

    ``response`` is the translation phase-correlation peak of the pre-aligned pair (0..1). ``candidates``
    holds every rotation the magnitude spectrum cannot tell apart (r, r + 90, r + 180, r + 270 deg: a
    periodic floor makes them look alike) as ``(matrix, rotation_rad, response)``, best response first.
    """

    matrix: FloatArray
    rotation_rad: float
    scale: float
    response: float
    candidates: tuple[tuple[FloatArray, float, float], ...] = ()


@functools.lru_cache(maxsize=4)
def _highpass(size_px: int) -> Float32Array:
    """Reddy & Chatterji's high-pass emphasis (1 - X)(2 - X), X = cos(pi u) cos(pi v), centred spectrum."""
    u = np.linspace(-0.5, 0.5, size_px, endpoint=False)
    X = np.cos(np.pi * u)[:, None] * np.cos(np.pi * u)[None, :]
    weight = ((1.0 - X) * (2.0 - X)).astype(np.float32)
    weight.setflags(write=False)
    return weight


@functools.lru_cache(maxsize=4)
def _circular_window(size_px: int) -> Float32Array:
    """Radially symmetric Hann window: no axis-aligned leakage that would pin the rotation at 0 deg."""
    u = np.arange(size_px) - (size_px - 1) / 2.0
    r = np.hypot(u[:, None], u[None, :]) / (size_px / 2.0)
    window = np.where(r < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(r, 1.0))), 0.0).astype(np.float32)
    window.setflags(write=False)
    return window


#: Radial band of the log-polar spectrum used (fraction of the Nyquist radius): the lowest radii carry the
#: window's leakage, the highest the pixel lattice's aliasing; both are fixed in orientation.
_RADIAL_BAND = (0.04, 0.7)


def _log_polar_magnitude(square: Float32Array, angle_bins: int) -> Float32Array:
    """Log-polar map (angle_bins, radial band) of the high-passed, centred log-magnitude spectrum."""
    size = square.shape[0]
    windowed = (square - square.mean()) * _circular_window(size)
    spectrum = np.fft.fftshift(np.abs(np.fft.fft2(windowed))).astype(np.float32)
    magnitude = np.log1p(spectrum * _highpass(size))
    radius = size / 2.0
    cols = size // 2
    polar = cv2.warpPolar(
        magnitude,
        (cols, angle_bins),
        (size / 2.0, size / 2.0),
        radius,
        cv2.INTER_LINEAR | cv2.WARP_POLAR_LOG,
    )
    # Column j holds radius exp(j * log(radius) / cols).
    lo, hi = (round(math.log(f * radius) / math.log(radius) * cols) for f in _RADIAL_BAND)
    return np.ascontiguousarray(polar[:, lo:hi])


def _similarity_about(centre_xy: tuple[float, float], rotation_rad: float, scale: float) -> FloatArray:
    """3x3 similarity rotating by ``rotation_rad`` and scaling by ``scale`` about ``centre_xy``."""
    cx, cy = centre_xy
    c, s = scale * math.cos(rotation_rad), scale * math.sin(rotation_rad)
    return np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0.0, 0.0, 1.0]])


def warp_into(
    frame_b: U8Array, matrix_a_b: FloatArray, shape: tuple[int, int], interpolation: int = cv2.INTER_LINEAR
) -> U8Array:
    """Frame b resampled into frame a's pixels: out(x) = b(matrix_a_b @ x), size ``shape`` (H, W), with
    OpenCV's ``interpolation`` (bilinear by default)."""
    return np.asarray(
        cv2.warpPerspective(
            frame_b,
            matrix_a_b,
            (shape[1], shape[0]),
            flags=interpolation | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_REFLECT,
        ),
        dtype=np.uint8,
    )


def estimate_global_alignment(frame_a: U8Array, frame_b: U8Array, settings: YawSettings) -> GlobalAlignment:
    """Fourier-Mellin estimate of the similarity frame a -> frame b on downsampled whole frames.

    Rotation and scale come from phase correlation of the log-polar magnitude spectra of the central
    squares (translation-invariant); the 90/180 deg ambiguities (a magnitude spectrum is symmetric, a periodic
    floor's is 90 deg symmetric too) and the translation come from phase correlation of frame a with frame b
    warped back by each candidate r + k 90 deg; the best is the default, all are kept for disambiguation.
    """
    check_grey_image(frame_a, "frame_a")
    check_grey_image(frame_b, "frame_b")
    size = settings.global_size_px
    factor = size / min(min(frame_a.shape), min(frame_b.shape))

    def small(frame: U8Array) -> Float32Array:
        h, w = frame.shape
        resized = cv2.resize(frame, (round(w * factor), round(h * factor)), interpolation=cv2.INTER_AREA)
        return resized.astype(np.float32)

    small_a, small_b = small(frame_a), small(frame_b)

    def centre_square(image: Float32Array) -> Float32Array:
        h, w = image.shape
        y0, x0 = (h - size) // 2, (w - size) // 2
        return np.ascontiguousarray(image[y0 : y0 + size, x0 : x0 + size])

    bins = settings.global_angle_bins
    polar_a = _log_polar_magnitude(centre_square(small_a), bins)
    polar_b = _log_polar_magnitude(centre_square(small_b), bins)
    # The angle axis is periodic; only the radial axis needs a window.
    radial_window = np.tile(np.hanning(polar_a.shape[1] + 2)[1:-1], (bins, 1))
    (d_radial, d_angle), _ = cv2.phaseCorrelate(
        polar_a.astype(np.float64), polar_b.astype(np.float64), radial_window
    )
    rotation = 2.0 * math.pi * d_angle / bins
    log_base = math.log(size / 2.0) / (size // 2)  # log-radius per column
    scale = math.exp(-d_radial * log_base)  # the spectrum shrinks when the image grows
    h, w = small_a.shape
    centre = ((w - 1) / 2.0, (h - 1) / 2.0)
    window = cv2.createHanningWindow((w, h), cv2.CV_64F)
    D = np.diag([factor, factor, 1.0])
    D_inv = np.linalg.inv(D)
    candidates: list[tuple[FloatArray, float, float]] = []
    for quarter in range(4):
        candidate = rotation + quarter * math.pi / 2.0
        S = _similarity_about(centre, candidate, scale)
        aligned = cv2.warpPerspective(
            small_b, S, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT
        )
        (dx, dy), response = cv2.phaseCorrelate(
            small_a.astype(np.float64), aligned.astype(np.float64), window
        )
        shift = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])
        # Small pixel x_s = f * x (pixel-centre offsets cancel in rotation and scale, shift < 1 px).
        matrix = D_inv @ (S @ shift) @ D
        candidates.append((matrix, math.atan2(math.sin(candidate), math.cos(candidate)), float(response)))
    candidates.sort(key=lambda c: -c[2])
    matrix, wrapped, response = candidates[0]
    return GlobalAlignment(
        matrix=matrix, rotation_rad=wrapped, scale=scale, response=response, candidates=tuple(candidates)
    )
