"""The central stage's pair logic (paper A, Algorithm 1, made honest): the patch fit on undistorted
correspondences, its refinement, the prior- and global-prealigned fallbacks and which result is trusted."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import Enum

import cv2
import numpy as np

from common.camera import CameraModel
from common.errors import InputError
from common.types import FloatArray, U8Array
from common.yaw.correlation import PatchSpectra, measure_patches, patch_spectra, patch_spectra_from_crops
from common.yaw.fit import (
    ModelFit,
    fit_correspondences,
    rotation_of_homography_rad,
    shift_of_homography_px,
)
from common.yaw.global_align import estimate_global_alignment, warp_into
from common.yaw.grid import IntArray, PatchGrid, pyramid_image
from common.yaw.honest import Prior, PriorSource, choose_rotation, measured_variance_rad2, plausible
from common.yaw.level import Levelling
from common.yaw.measurement import PatchMeasurement
from common.yaw.settings import FitModel, YawSettings

logger = logging.getLogger(__name__)


#: A frame whose grey-level std (0..255) is below this has nothing to correlate (black, saturated).
_MIN_FRAME_STD = 2.0
#: The global alignment is trusted alone (flagged low-confidence) above this correlation response.
_MIN_GLOBAL_RESPONSE = 0.05
#: How the refinement turns frame k's pyramid level back: bilinear, measured against bicubic and Lanczos by
#: ``capataz bench refine --suite warp``. Bilinear interpolation shifts fine texture by other than the
#: fractional shift asked for, so on pure turns the refined turn reads up to 0.04 deg long at 0.3 deg (short
#: at 0.8 deg); through Lanczos, under 0.01 deg. But on the field suite's flights that error offsets part of
#: the window's pull (which reads turns short) and Lanczos made the integrated yaw drift more at 20 fps (max
#: AME 0.54 -> 0.84 deg on ``field``, seed 0), less at 60 fps (1.0 -> 0.34 deg on ``checkerboard``):
#: bilinear stays until the pull is removed too (docs/methods.md, "Frame rates").
REFINE_INTERPOLATION = cv2.INTER_LINEAR


class EstimateMethod(Enum):
    """Which stage produced the measured delta."""

    PATCHES = "patches"  # patch fit on the raw pair
    REFINED = "refined"  # patch fit, then again on frame k turned back by that fit's rotation
    PRIOR_PREALIGNED = "prior_prealigned"  # frame k turned back by the prior (gyro / held rate), then patches
    GLOBAL_PREALIGNED = "global_prealigned"  # Fourier-Mellin pre-alignment, then the patch fit
    GLOBAL_ONLY = "global_only"  # patch fit failed even after pre-alignment; global estimate only
    NONE = "none"  # nothing usable (textureless, garbage)


@dataclass(frozen=True)
class Lens:
    """Where correspondences live: undistorted patch centres, the rotation centre and the lever arm; with
    ``to_nadir`` (3, 3) they are moved on into the view of a virtual camera at the same place looking
    straight down the body's -z (a camera mounted off the down mount: there a yaw is a turn about the
    centre, and a translation over the floor no turn at all)."""

    camera: CameraModel | None
    centre_px: tuple[float, float]
    src_px: FloatArray  # (P, 2) patch centres, undistorted (and in the nadir view)
    lever_px: float
    #: (P, 2) patch centres undistorted, before the nadir view (what a pair's level views map)
    undistorted_px: FloatArray
    to_nadir: FloatArray | None = None
    #: the focal length (px; the geometric mean of ``fx`` and ``fy``), None without intrinsics
    focal_px: float | None = None
    #: one pair's level views (:func:`conclude_pair`'s copy of the lens), instead of the fixed nadir view
    levelling: Levelling | None = None


def _mapped(homography: FloatArray, points_px: FloatArray) -> FloatArray:
    mapped = np.hstack([points_px, np.ones((points_px.shape[0], 1))]) @ homography.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(mapped[:, :2] / mapped[:, 2:3], dtype=np.float64)


def lens_of(grid: PatchGrid, settings: YawSettings, R_nadir_camera: FloatArray | None = None) -> Lens:
    """The lens of the grid's frames; ``R_nadir_camera`` (the camera's axes in the virtual down camera's,
    ``R_BODY_CAMERA_DOWN^T R_body_camera``) rectifies the correspondences into the nadir view (needs the
    settings' camera: its intrinsics)."""
    height, width = grid.frame_shape
    camera = settings.camera
    if camera is None:
        centre = ((width - 1) / 2.0, (height - 1) / 2.0)
        src = grid.centres_px
    else:
        if camera.shape != grid.frame_shape:
            if abs(camera.width / width - camera.height / height) > 1e-9:
                raise InputError(
                    f"camera is {camera.width}x{camera.height}, frames are {width}x{height} (other aspect)"
                )
            camera = camera.scaled(width / camera.width)
        centre = (camera.cx, camera.cy)
        src = camera.undistort_px(grid.centres_px)
    undistorted = src
    to_nadir = None
    if R_nadir_camera is not None:
        if camera is None:
            raise InputError(
                "the nadir view of a mounted camera needs the camera's intrinsics (a calibration)"
            )
        to_nadir = camera.K @ R_nadir_camera @ camera.K_inv
        src = _mapped(to_nadir, src)
    lever = float(np.median(np.hypot(src[:, 0] - centre[0], src[:, 1] - centre[1])))
    focal = None if camera is None else math.sqrt(camera.fx * camera.fy)
    return Lens(camera, centre, src, lever, undistorted, to_nadir, focal)


def frame_is_flat(frame_u8: U8Array) -> bool:
    small = frame_u8[::4, ::4]
    return bool(float(np.std(small)) < _MIN_FRAME_STD)


def fit_measurement(
    grid: PatchGrid,
    lens: Lens,
    measurement: PatchMeasurement,
    settings: YawSettings,
    matrix: FloatArray | None = None,
) -> ModelFit:
    """Fit patch centre -> centre + shift (mapped by the pre-alignment ``matrix`` when given: the shift was
    measured against frame k warped back by it), both undistorted through the lens model first, then moved
    into the fixed nadir view or, with the lens's ``levelling``, into each frame's level view
    (:mod:`common.yaw.level`)."""
    valid = measurement.valid
    index = measurement.indices[valid]
    dst = grid.centres_px[index] + measurement.shift_px[valid]
    if matrix is not None:
        mapped = np.hstack([dst, np.ones((dst.shape[0], 1))]) @ matrix.T
        dst = mapped[:, :2] / mapped[:, 2:3]
    src, to_view = lens.src_px[index], lens.to_nadir
    levelling = lens.levelling
    if levelling is not None and lens.camera is not None:
        src, to_view = _mapped(levelling.before, lens.undistorted_px[index]), levelling.after
    if lens.camera is not None and dst.size:
        dst = lens.camera.undistort_px(dst) if np.all(np.isfinite(dst)) else np.full_like(dst, np.nan)
        if to_view is not None:  # inline: a frame's walk enters this module once more per call back into it
            viewed = np.hstack([dst, np.ones((dst.shape[0], 1))]) @ to_view.T
            with np.errstate(divide="ignore", invalid="ignore"):
                dst = viewed[:, :2] / viewed[:, 2:3]
        keep = np.all(np.isfinite(dst), axis=1)
        src, dst = src[keep], dst[keep]
    return fit_correspondences(src, dst, settings)


def fit_is_good(fit: ModelFit, measurement: PatchMeasurement, settings: YawSettings) -> bool:
    """Enough of the valid (textured, unambiguous) patches agree; low texture lowers the confidence only."""
    return bool(fit.ok and fit.inlier_count >= settings.min_inlier_fraction * measurement.n_valid)


@dataclass(frozen=True, eq=False)
class PairResult:
    """One pair's outcome; ``variance_rad2`` is the variance of ``delta_rad`` if it is trusted (measured)."""

    homography: FloatArray
    method: EstimateMethod
    fit: ModelFit
    measurement: PatchMeasurement
    low_confidence: bool
    delta_rad: float
    trusted: bool
    variance_rad2: float


def _result(
    homography: FloatArray,
    method: EstimateMethod,
    fit: ModelFit,
    measurement: PatchMeasurement,
    lens: Lens,
    settings: YawSettings,
    prior: Prior,
    good: bool,
) -> PairResult:
    delta, shift_px = 0.0, 0.0
    if method is not EstimateMethod.NONE:
        delta = rotation_of_homography_rad(homography, lens.centre_px)
        shift_px = shift_of_homography_px(homography, lens.centre_px)
    low = not good or fit.residual_px > settings.max_residual_px or method in _UNTRUSTED
    warped = method is not EstimateMethod.PATCHES
    valid = measurement.confidence[measurement.valid]  # the patches' first-to-second peak ratios
    peak_ratio = float(np.median(valid)) if valid.size else 1.0
    variance = measured_variance_rad2(
        fit.residual_px,
        fit.inlier_count,
        measurement.indices.size,
        lens.lever_px,
        warped,
        shift_px,
        lens.focal_px,
        peak_ratio,
        0.0 if warped else delta,
    )
    trusted = not low and plausible(delta, prior, settings)
    return PairResult(homography, method, fit, measurement, low, delta, trusted, variance)


_UNTRUSTED = (EstimateMethod.GLOBAL_ONLY, EstimateMethod.NONE)

#: Measures the refinement's patches elsewhere (a master: on the members that measured them):
#: ``(indices, frame k's level crops turned back)`` -> their shifts against frame k-1's crops at the same
#: indices, computed as :func:`common.yaw.correlation.measure_patches` does (the results equal the local ones)
RefineMeasure = Callable[[IntArray, U8Array], PatchMeasurement]


def prealigned_pair(
    previous_frame: U8Array,
    frame_u8: U8Array,
    grid: PatchGrid,
    lens: Lens,
    settings: YawSettings,
    matrix: FloatArray,
    method: EstimateMethod,
    previous_spectra: PatchSpectra | None,
    prior: Prior,
    fit_model: FitModel,
    refine_measure: RefineMeasure | None = None,
) -> PairResult:
    """Patch stage on frame k warped back by ``matrix`` (frame k-1 px -> frame k px), fitted through it.

    The refinement (``EstimateMethod.REFINED``, small turns, the frequent case) warps frame k's pyramid level
    (a quarter of the pixels at level 1; level pixel i is full-resolution pixel 2^L i, ``cv2.pyrDown``'s
    alignment) and measures the sub-grid of :func:`refine_indices`; the fallbacks (large turns, rare) warp
    the full frame and then reduce it, which keeps more detail (the dropped-frames hover drifts 0.05 deg less
    over 120 pairs), and measure every patch. ``refine_measure`` measures the refinement's crops elsewhere
    (the previous frame's spectra are then not needed here).
    """
    wanted = refine_indices(settings) if method is EstimateMethod.REFINED else None
    if wanted is not None and refine_measure is not None:
        turned = _turned_level(frame_u8, matrix, settings)
        measurement = refine_measure(wanted, grid.crop_level(turned, wanted))
        return _fitted(grid, lens, settings, matrix, method, measurement, prior, fit_model)
    if previous_spectra is None:
        before = patch_spectra(previous_frame, grid, wanted, settings)
    elif wanted is None:
        before = previous_spectra
    else:
        keep = np.isin(previous_spectra.indices, wanted)
        before = PatchSpectra(
            previous_spectra.indices[keep], previous_spectra.spectra[keep], previous_spectra.texture_std[keep]
        )
    if method is EstimateMethod.REFINED:
        aligned = _turned_level(frame_u8, matrix, settings)
    else:
        aligned = grid.level_image(warp_into(frame_u8, matrix, grid.frame_shape))
    current = patch_spectra_from_crops(grid.crop_level(aligned, before.indices), before.indices, settings)
    measurement = measure_patches(before, current, settings)
    return _fitted(grid, lens, settings, matrix, method, measurement, prior, fit_model)


def _turned_level(frame_u8: U8Array, matrix: FloatArray, settings: YawSettings) -> U8Array:
    """Frame k's pyramid level warped back by ``matrix`` (full-resolution px), the refinement's image."""
    to_full = np.diag([float(settings.scale), float(settings.scale), 1.0])
    level = pyramid_image(frame_u8, settings.level)
    return warp_into(level, np.linalg.inv(to_full) @ matrix @ to_full, level.shape, REFINE_INTERPOLATION)


def _fitted(
    grid: PatchGrid,
    lens: Lens,
    settings: YawSettings,
    matrix: FloatArray,
    method: EstimateMethod,
    measurement: PatchMeasurement,
    prior: Prior,
    fit_model: FitModel,
) -> PairResult:
    """The pair result of shifts measured on frame k warped back by ``matrix``."""
    fit = fit_measurement(grid, lens, measurement, replace(settings, fit_model=fit_model), matrix)
    good = fit_is_good(fit, measurement, settings)
    return _result(fit.homography, method, fit, measurement, lens, settings, prior, good)


def refine_indices(settings: YawSettings) -> IntArray:
    """The patches the refinement measures (row-major grid indices): every k-th column and row, centred, with
    k the smallest step that keeps at most ``refine_max_patches`` of the ``grid_cols`` x ``grid_rows``."""
    cols, rows = settings.grid_cols, settings.grid_rows
    k = 1
    while -(-cols // k) * -(-rows // k) > settings.refine_max_patches:
        k += 1
    col0, row0 = ((cols - 1) % k) // 2, ((rows - 1) % k) // 2
    return np.array([r * cols + c for r in range(row0, rows, k) for c in range(col0, cols, k)], dtype=np.intp)


def rotation_about(centre: tuple[float, float], rotation_rad: float) -> FloatArray:
    cx, cy = centre
    c, s = math.cos(rotation_rad), math.sin(rotation_rad)
    return np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy], [0.0, 0.0, 1.0]])


def conclude_pair(
    previous_frame: U8Array,
    frame_u8: U8Array,
    measurement: PatchMeasurement,
    grid: PatchGrid,
    lens: Lens,
    settings: YawSettings,
    previous_spectra: PatchSpectra | None,
    prior: Prior,
    check_global: bool,
    refine_measure: RefineMeasure | None = None,
    levelling: Levelling | None = None,
) -> PairResult:
    """Raw patch fit (in the frames' level views with ``levelling``, :mod:`common.yaw.level`); if untrusted,
    the patches on frame k turned back by an informative prior; if still untrusted and there is no gyro, the
    global stage's candidates r + k 90 deg, disambiguated by their responses and the prior, each verified by
    the patch stage. The cost is bounded by the gyro: with it the global stage never runs (the gyro bridges
    what the patches cannot measure). ``refine_measure`` measures the refinement's patches elsewhere
    (:data:`RefineMeasure`; the fallbacks, rare, are measured here)."""
    if levelling is not None:
        lens = replace(lens, levelling=levelling)
    fit = fit_measurement(grid, lens, measurement, settings)
    good = fit_is_good(fit, measurement, settings)
    patches = _result(fit.homography, EstimateMethod.PATCHES, fit, measurement, lens, settings, prior, good)
    if patches.trusted and not check_global:
        if abs(patches.delta_rad) < math.radians(settings.refine_min_deg):
            return patches
        # The window pulls each patch's shift towards zero by a texture-dependent fraction (a few % on a
        # checkerboard): measure again with frame k turned back, where the remaining shifts are tiny.
        matrix = rotation_about(lens.centre_px, patches.delta_rad)
        refined = prealigned_pair(
            previous_frame, frame_u8, grid, lens, settings, matrix,
            EstimateMethod.REFINED, previous_spectra, prior, settings.fit_model, refine_measure,
        )  # fmt: skip
        return refined if refined.trusted else patches
    if frame_is_flat(previous_frame) or frame_is_flat(frame_u8):
        logger.debug("flat frame: no yaw")
        return _result(np.eye(3), EstimateMethod.NONE, fit, measurement, lens, settings, prior, False)
    if prior.informative and not check_global:
        matrix = rotation_about(lens.centre_px, prior.delta_rad)
        turned = prealigned_pair(
            previous_frame, frame_u8, grid, lens, settings, matrix,
            EstimateMethod.PRIOR_PREALIGNED, previous_spectra, prior, settings.prealigned_fit_model,
        )  # fmt: skip
        if turned.trusted or prior.source is PriorSource.GYRO:
            return turned
    alignment = estimate_global_alignment(previous_frame, frame_u8, settings)
    if patches.trusted and alignment.response < _MIN_GLOBAL_RESPONSE:
        return patches
    logger.debug("patch fit %s (%d/%d inliers): global stage", good, fit.inlier_count, measurement.n_valid)
    candidates = [(rotation, response) for _, rotation, response in alignment.candidates]
    chosen = choose_rotation(candidates, prior, settings)
    if chosen is not None and alignment.candidates[chosen][2] >= _MIN_GLOBAL_RESPONSE:
        prealigned = prealigned_pair(
            previous_frame, frame_u8, grid, lens, settings, alignment.candidates[chosen][0],
            EstimateMethod.GLOBAL_PREALIGNED, previous_spectra, prior, settings.prealigned_fit_model,
        )  # fmt: skip
        if prealigned.trusted or (not patches.trusted and prealigned.fit.ok):
            return prealigned
    if patches.trusted:
        return patches
    matrix = alignment.matrix if chosen is None else alignment.candidates[chosen][0]
    return _result(matrix, EstimateMethod.GLOBAL_ONLY, fit, measurement, lens, settings, prior, False)
