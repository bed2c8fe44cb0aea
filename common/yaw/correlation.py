"""The distributable per-patch stage: cached patch spectra and phase correlation (paper A, Algorithm 2).

A frame's patch spectra are computed once (``patch_spectra``) and reused as the "previous" of the
next frame, which halves the forward transforms of the paper's ``cv2.phaseCorrelate`` per pair.
Everything is batched over patches; a worker may compute any subset of patch indices.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
import scipy.fft

from common.errors import InputError
from common.types import Float32Array, FloatArray, U8Array
from common.yaw.grid import IntArray, PatchGrid
from common.yaw.measurement import PatchMeasurement
from common.yaw.settings import FftBackend, YawError, YawSettings

ComplexArray = npt.NDArray[np.complex64]

#: The backends whose spectra are the real transform's half (s, s // 2 + 1); OpenCV's are full (s, s).
HALF_SPECTRUM_BACKENDS = frozenset({FftBackend.NUMPY, FftBackend.SCIPY})

#: Peaks closer than this (level px, per axis) to the main peak do not count as a second peak.
_SECOND_PEAK_EXCLUSION_PX = 2


@dataclass(frozen=True, eq=False)
class PatchSpectra:
    """Windowed spectra of a subset of one frame's patches.

    ``spectra`` is complex64 (n, s, s) for the OpenCV backend or (n, s, s // 2 + 1) for numpy and scipy;
    ``texture_std`` (n,) is each crop's grey-level standard deviation (0..255).
    """

    indices: IntArray
    spectra: ComplexArray
    texture_std: Float32Array


@functools.lru_cache(maxsize=8)
def patch_window(size_px: int, taper: float) -> Float32Array:
    """Separable Tukey window (size, size) float32: a flat top with cosine tapers of ``taper`` of the width.

    ``taper = 1`` is the Hann window (``cv2.createHanningWindow``); smaller tapers keep more of the patch,
    which reduces the window's pull of the correlation peak towards zero shift.
    """
    i = np.arange(size_px, dtype=np.float64) / (size_px - 1)
    edge = taper / 2.0
    w = np.ones(size_px)
    if edge > 0.0:
        low, high = i < edge, i > 1.0 - edge
        w[low] = 0.5 * (1.0 - np.cos(np.pi * i[low] / edge))
        w[high] = 0.5 * (1.0 - np.cos(np.pi * (1.0 - i[high]) / edge))
    window = np.outer(w, w).astype(np.float32)
    window.setflags(write=False)
    return window


@functools.lru_cache(maxsize=16)
def peak_weighting(size_px: int, sigma_px: float, half: bool) -> Float32Array:
    """Gaussian weight of the cross-power spectrum: the correlation peak becomes a Gaussian of ``sigma_px``.

    A Gaussian of std sigma (pixels) has the transform exp(-2 pi^2 sigma^2 nu^2), nu in cycles/pixel; it
    also damps the noisiest (highest) frequencies. ``half`` gives the rfft layout (s, s // 2 + 1), else
    the full (s, s) layout.
    """
    fy = np.fft.fftfreq(size_px)
    fx = np.fft.rfftfreq(size_px) if half else np.fft.fftfreq(size_px)
    nu2 = fy[:, None] ** 2 + fx[None, :] ** 2
    weight = np.exp(-2.0 * np.pi**2 * sigma_px**2 * nu2).astype(np.float32)
    weight.setflags(write=False)
    return weight


def check_crops(crops: object, settings: YawSettings) -> U8Array:
    """Crops must be uint8 (n, s, s) with s = settings.patch_size_px."""
    if not isinstance(crops, np.ndarray) or crops.dtype != np.uint8:
        raise InputError(f"crops must be a uint8 numpy array (n, s, s), got {type(crops)}")
    s = settings.patch_size_px
    if crops.ndim != 3 or crops.shape[1:] != (s, s):
        raise InputError(f"crops must have shape (n, {s}, {s}), got {crops.shape}")
    return crops


def windowed_patches(crops_u8: U8Array, settings: YawSettings) -> tuple[Float32Array, Float32Array]:
    """Zero-mean, Hann-windowed float32 patches (n, s, s) and each crop's grey std (n,)."""
    patches = crops_u8.astype(np.float32)
    mean = patches.mean(axis=(1, 2), keepdims=True)
    patches -= mean
    texture_std = np.sqrt(np.mean(patches * patches, axis=(1, 2)))
    patches *= patch_window(settings.patch_size_px, settings.window_taper)
    return patches, texture_std.astype(np.float32)


#: Pixels of the patches the core windows, transforms and correlates at a time (:func:`run_slices`). pocketfft
#: transforms a batch's columns across the whole batch, which leaves the cache once a frame's patches are
#: large: a 128 px patch's forward transform costs about twice as much in a batch of 60 as in runs of 8
#: (``capataz bench fft``). Runs of this many pixels keep the batched call's speed for small patches (128
#: patches of 32 px) and the runs' for large ones (8 of 128 px, 2 of 256 px); each patch's transform is the
#: same 1-D passes either way, so the bits do not depend on the run.
FFT_RUN_PIXELS = 1 << 17


def fft_run(size_px: int) -> int:
    """How many patches of ``size_px`` one run holds (:data:`FFT_RUN_PIXELS`; at least one)."""
    return max(1, FFT_RUN_PIXELS // (size_px * size_px))


def run_slices(n: int, size_px: int) -> Iterator[slice]:
    """The runs of :func:`fft_run` patches of ``size_px`` that a frame's ``n`` patches are transformed in."""
    run = fft_run(size_px)
    for start in range(0, n, run):
        yield slice(start, min(start + run, n))


def forward_transform(patches: Float32Array, backend: FftBackend) -> ComplexArray:
    """Batched 2-D transforms of real patches (n, s, s): full spectra (OpenCV) or half spectra (numpy, scipy).

    numpy's pocketfft transforms float32 in double precision (then cast back); scipy's in single precision,
    2-10 times faster forward (``capataz bench fft``)."""
    if backend is FftBackend.SCIPY:
        return np.asarray(scipy.fft.rfft2(patches, workers=1), dtype=np.complex64)
    if backend is FftBackend.NUMPY:
        return np.fft.rfft2(patches).astype(np.complex64, copy=False)
    n, height, width = patches.shape
    out = np.empty((n, height, width, 2), dtype=np.float32)
    for i in range(n):
        cv2.dft(patches[i], out[i], flags=cv2.DFT_COMPLEX_OUTPUT)
    return out.view(np.complex64)[..., 0]


def inverse_transform(spectra: ComplexArray, size_px: int, backend: FftBackend) -> Float32Array:
    """Batched inverse of Hermitian spectra to real surfaces (n, s, s)."""
    if backend is FftBackend.SCIPY:
        return np.asarray(scipy.fft.irfft2(spectra, s=(size_px, size_px), workers=1), dtype=np.float32)
    if backend is FftBackend.NUMPY:
        return np.fft.irfft2(spectra, s=(size_px, size_px)).astype(np.float32, copy=False)
    n = spectra.shape[0]
    pairs = spectra[..., None].view(np.float32)  # (n, s, s, 2)
    out = np.empty((n, size_px, size_px), dtype=np.float32)
    flags = cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE
    for i in range(n):
        cv2.dft(pairs[i], out[i], flags=flags)
    return out


def normalised_cross_power(
    previous: ComplexArray, current: ComplexArray, weight: Float32Array | None = None
) -> Float32Array:
    """Cross-power spectrum, paper A's ``C = (Ia . conj(Ib)) / (|Ia| |Ib|)`` with Ia = current, Ib = previous.

    Returned as float32 (n, s, w, 2) [re, im] pairs (the inverse gives a peak at the shift of current
    vs previous); normalised by ``|Ia . conj(Ib)|`` plus a tiny floor so textureless patches give zeros,
    and multiplied by ``weight`` (s, w) when given (in the same pass).

    Written as separate real ufuncs (each correctly rounded) rather than complex64 arithmetic, whose
    SIMD and scalar paths (fused multiply-adds) differ in the last bit depending on the batch length
    and alignment: a worker's subset of patches must give exactly the bits of the whole batch.
    """
    a_re, a_im = previous.real, previous.imag
    b_re, b_im = current.real, current.imag
    out = np.empty((*current.shape, 2), dtype=np.float32)
    re, im = out[..., 0], out[..., 1]
    np.multiply(b_re, a_re, out=re)
    re += b_im * a_im
    np.multiply(b_im, a_re, out=im)
    im -= b_re * a_im
    magnitude = np.sqrt(re * re + im * im)
    magnitude += np.float32(1e-6) * (magnitude.max(axis=(1, 2), keepdims=True) + np.float32(1e-30))
    factor = np.divide(weight, magnitude) if weight is not None else np.reciprocal(magnitude)
    out *= factor[..., None]
    return out


def correlation_surfaces(
    previous: ComplexArray, current: ComplexArray, weight: Float32Array, settings: YawSettings
) -> Float32Array:
    """The weighted cross-power spectra's inverse transforms, the correlation surfaces (n, s, s), computed in
    runs of :func:`fft_run` patches so that each run's cross power is still in the cache when it is
    transformed (the whole batch's is 6.4 MB for 192 patches of 128 px). Each patch's bits are the batch's."""
    size = settings.patch_size_px
    surfaces = np.empty((current.shape[0], size, size), dtype=np.float32)
    for part in run_slices(current.shape[0], size):
        cross = normalised_cross_power(previous[part], current[part], weight)
        surfaces[part] = inverse_transform(cross.view(np.complex64)[..., 0], size, settings.fft_backend)
    return surfaces


def patch_spectra_from_crops(
    crops_u8: U8Array, indices: npt.ArrayLike, settings: YawSettings
) -> PatchSpectra:
    """Spectra of already-cropped patches (what a worker receives); same bits as ``patch_spectra``."""
    crops = check_crops(crops_u8, settings)
    idx = np.asarray(indices, dtype=np.intp)
    if idx.shape != (crops.shape[0],):
        raise InputError(f"indices must have shape ({crops.shape[0]},) like the crops, got {idx.shape}")
    # windowed and transformed in runs of fft_run patches, each run's float patches still in the cache
    n, size = crops.shape[0], settings.patch_size_px
    width = size // 2 + 1 if settings.fft_backend in HALF_SPECTRUM_BACKENDS else size
    spectra = np.empty((n, size, width), dtype=np.complex64)
    texture_std = np.empty((n,), dtype=np.float32)
    for part in run_slices(n, size):
        patches, texture_std[part] = windowed_patches(crops[part], settings)
        spectra[part] = forward_transform(patches, settings.fft_backend)
    return PatchSpectra(indices=idx, spectra=spectra, texture_std=texture_std)


def patch_spectra(
    frame_u8: U8Array, grid: PatchGrid, indices: npt.ArrayLike | None, settings: YawSettings
) -> PatchSpectra:
    """Spectra of the patches ``indices`` (all when None) of one full-resolution frame, checked where it
    entered the core (:meth:`~common.yaw.tracker.YawTracker.track`)."""
    idx = grid.all_indices if indices is None else indices
    return patch_spectra_from_crops(grid.crop_level(grid.level_image(frame_u8), idx), idx, settings)


@functools.lru_cache(maxsize=16)
def window_overlap_log(size_px: int, taper: float) -> FloatArray:
    """log of the 1-D window's normalised autocorrelation at the cyclic lags 0..s-1 (lag i > s/2 is i - s).

    A shift d seen through a fixed window gives a correlation surface close to ``g(x - d) * a(x)``
    with ``a`` the window's autocorrelation: the factor ``a`` pulls the peak towards zero by about
    d * sigma_peak^2 / sigma_a^2 (2.5 % for 32 px Hann patches). Dividing it out removes that bias.
    """
    w = patch_window(size_px, taper)[size_px // 2].astype(np.float64)
    w = w / np.sqrt(np.sum(w * w))
    full = np.correlate(w, w, mode="full")  # lags -(s-1) .. s-1
    lags = np.arange(size_px)
    lags = np.where(lags > size_px // 2, lags - size_px, lags)
    values = np.log(np.maximum(full[lags + size_px - 1], 1e-12))
    values.setflags(write=False)
    return values


def subpixel_peaks(
    surfaces: Float32Array, overlap_log: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Peak position (n, 2) [dx, dy] in (-s/2, s/2], peak height (n,) and peak/second-peak ratio (n,).

    The surfaces are Gaussian-shaped around their peak (see ``peak_weighting``), so a 3-point
    parabola through the log of the peak and its neighbours is the sub-pixel estimate per axis;
    ``overlap_log`` (s,) (see ``window_overlap_log``) is subtracted from the logs first.
    """
    n, height, width = surfaces.shape
    flat = surfaces.reshape(n, -1)
    arg = np.argmax(flat, axis=1)
    py, px = np.divmod(arg, width)
    rows = np.arange(n)
    c0 = flat[rows, arg].astype(np.float64)
    tiny = 1e-12
    # The peak and its 4 neighbours (n, 5): centre, x-1, x+1, y-1, y+1.
    ys = np.stack([py, py, py, (py - 1) % height, (py + 1) % height], axis=1)
    xs = np.stack([px, (px - 1) % width, (px + 1) % width, px, px], axis=1)
    samples = np.maximum(surfaces[rows[:, None], ys, xs].astype(np.float64), tiny)
    # math.log per value, not np.log: numpy's SIMD and scalar log paths differ in the last bit, and which
    # path a patch takes depends on the batch length. A worker's subset must give the same bits.
    logs = np.array([math.log(v) for v in samples.ravel().tolist()]).reshape(n, 5)
    if overlap_log is not None:
        logs -= np.stack(
            [
                overlap_log[px] + overlap_log[py],
                overlap_log[xs[:, 1]],
                overlap_log[xs[:, 2]],
                overlap_log[ys[:, 3]],
                overlap_log[ys[:, 4]],
            ],
            axis=1,
        )
        # Each 3-point parabola sees one axis: remove the other axis' (common) overlap factor of the centre.
        centre_x = logs[:, 0] + overlap_log[py]
        centre_y = logs[:, 0] + overlap_log[px]
    else:
        centre_x = centre_y = logs[:, 0]

    def vertex(minus: FloatArray, plus: FloatArray, centre: FloatArray) -> FloatArray:
        curvature = minus - 2.0 * centre + plus
        with np.errstate(divide="ignore", invalid="ignore"):
            offset = np.where(curvature < 0.0, 0.5 * (minus - plus) / curvature, 0.0)
        return np.clip(offset, -0.5, 0.5)

    sub_x = vertex(logs[:, 1], logs[:, 2], centre_x)
    sub_y = vertex(logs[:, 3], logs[:, 4], centre_y)
    # Wrap the integer peak to signed shifts.
    shift_x = np.where(px > width // 2, px - width, px) + sub_x
    shift_y = np.where(py > height // 2, py - height, py) + sub_y
    # Second peak: the maximum outside a small square around the main peak (cyclic).
    masked = surfaces.copy()
    offsets = np.arange(-_SECOND_PEAK_EXCLUSION_PX, _SECOND_PEAK_EXCLUSION_PX + 1)
    near_y = ((py[:, None] + offsets[None, :]) % height)[:, :, None]
    near_x = ((px[:, None] + offsets[None, :]) % width)[:, None, :]
    masked[rows[:, None, None], near_y, near_x] = -np.inf
    second = masked.reshape(n, -1).max(axis=1).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(second > tiny, c0 / np.maximum(second, tiny), np.where(c0 > tiny, np.inf, 0.0))
    return np.stack([shift_x, shift_y], axis=1), c0, ratio


def measure_patches(previous: PatchSpectra, current: PatchSpectra, settings: YawSettings) -> PatchMeasurement:
    """Phase correlation of each patch of frame k against its cached spectrum of frame k-1.

    Paper A, Algorithm 2 (DISPLACEMENT), with the previous spectrum reused instead of recomputed:
    cross-power spectrum (``normalised_cross_power``), weighted by a Gaussian (``peak_weighting``),
    inverse transform, sub-pixel peak corrected for the window (``subpixel_peaks``).
    """
    if previous.indices.shape != current.indices.shape or not np.array_equal(
        previous.indices, current.indices
    ):
        raise YawError("previous and current spectra must cover the same patch indices in the same order")
    if previous.spectra.shape != current.spectra.shape:
        raise YawError(f"spectra shapes differ: {previous.spectra.shape} vs {current.spectra.shape}")
    s = settings.patch_size_px
    half = settings.fft_backend in HALF_SPECTRUM_BACKENDS
    expected = (s, s // 2 + 1) if half else (s, s)
    if current.spectra.shape[1:] != expected:
        raise YawError(f"spectra have shape {current.spectra.shape[1:]}, settings expect {expected}")
    n = current.indices.size
    if n == 0:
        empty = np.zeros((0,), dtype=np.float64)
        return PatchMeasurement(
            current.indices, np.zeros((0, 2)), empty, empty, np.zeros((0,), dtype=np.bool_)
        )
    surfaces = correlation_surfaces(
        previous.spectra, current.spectra, peak_weighting(s, settings.peak_sigma_px, half), settings
    )
    overlap = window_overlap_log(s, settings.window_taper) * settings.overlap_correction
    shift_level, peak, ratio = subpixel_peaks(surfaces, overlap if settings.overlap_correction else None)
    textured = np.minimum(previous.texture_std, current.texture_std) >= settings.min_texture_std
    valid = textured & (ratio >= settings.min_peak_ratio) & np.all(np.isfinite(shift_level), axis=1)
    return PatchMeasurement(
        indices=current.indices,
        shift_px=shift_level * settings.scale,
        confidence=np.where(textured, ratio, 0.0),
        peak=peak,
        valid=valid,
    )
