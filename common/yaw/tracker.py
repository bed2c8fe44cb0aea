"""The central stage: robust fit, large-rotation fallback and yaw integration (paper A, Algorithm 1).

``YawTracker.track`` is literally ``patch_spectra`` + ``measure_patches`` (the distributable stage)
followed by ``YawTracker.conclude`` (the central stage), so a cluster that runs the first stage on
workers and the second on the master produces the same yaw.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from common.errors import InputError
from common.images import check_grey_image
from common.types import FloatArray
from common.yaw.correlation import (
    PatchMeasurement,
    PatchSpectra,
    measure_patches,
    merge_measurements,
    patch_spectra,
)
from common.yaw.fit import ModelFit, fit_correspondences, rotation_of_homography_rad
from common.yaw.global_align import GlobalAlignment, estimate_global_alignment, warp_into
from common.yaw.grid import PatchGrid, U8Array, make_patch_grid
from common.yaw.settings import YawSettings

logger = logging.getLogger(__name__)


#: A frame whose grey-level std (0..255) is below this has nothing to correlate (black, saturated).
_MIN_FRAME_STD = 2.0
#: The global alignment is trusted alone (flagged low-confidence) above this correlation response.
_MIN_GLOBAL_RESPONSE = 0.05


class EstimateMethod(Enum):
    """How a yaw estimate was obtained."""

    PATCHES = "patches"  # patch fit on the raw pair
    GLOBAL_PREALIGNED = "global_prealigned"  # Fourier-Mellin pre-alignment, then the patch fit
    GLOBAL_ONLY = "global_only"  # patch fit failed even after pre-alignment; global estimate only
    NONE = "none"  # nothing usable (textureless, garbage): delta yaw 0, low confidence


@dataclass(frozen=True, eq=False)
class YawEstimate:
    """Yaw of frame ``seq`` relative to frame ``seq - 1`` and integrated since frame 0.

    ``delta_yaw_rad`` is the change of the vehicle's yaw (ZYX yaw of q_world_body, CCW seen from above)
    for a downward camera (``R_BODY_CAMERA_DOWN``); ``homography`` (3, 3) maps frame seq-1 pixels to
    frame seq pixels. ``confidence`` in [0, 1] is the inlier fraction of the measured patches.
    """

    seq: int
    delta_yaw_rad: float
    yaw_rad: float
    inlier_count: int
    patch_count: int
    valid_count: int
    confidence: float
    low_confidence: bool
    method: EstimateMethod
    homography: FloatArray
    residual_px: float


@dataclass(frozen=True, eq=False)
class TrackerState:
    """Explicit tracker state: the last frame (needed only by the fallback) and, in-process, its spectra.

    Frames are kept by reference: callers must not modify a frame after passing it in.
    """

    seq: int
    yaw_rad: float
    previous_frame: U8Array
    previous_spectra: PatchSpectra | None


def delta_yaw_from_homography_rad(homography: FloatArray, grid: PatchGrid) -> float:
    """Vehicle yaw change from the image homography of a downward camera (``rotation_of_homography_rad``).

    With ``R_BODY_CAMERA_DOWN`` (image x = body -y, image y = body -x, optical axis = body -z) a yaw of
    +psi (CCW from above) turns the image content by +psi in the image's (x right, y down) axes.
    Evaluated at the frame centre.
    """
    height, width = grid.frame_shape
    return rotation_of_homography_rad(homography, ((width - 1) / 2.0, (height - 1) / 2.0))


def _frame_is_flat(frame_u8: U8Array) -> bool:
    small = frame_u8[::4, ::4]
    return bool(float(np.std(small)) < _MIN_FRAME_STD)


def _fit_measurement(grid: PatchGrid, measurement: PatchMeasurement, settings: YawSettings) -> ModelFit:
    valid = measurement.valid
    src = grid.centres_px[measurement.indices[valid]]
    return fit_correspondences(src, src + measurement.shift_px[valid], settings)


def _fit_is_good(fit: ModelFit, measurement: PatchMeasurement, settings: YawSettings) -> bool:
    """Enough of the measured patches agree (few valid patches = the rotation outran the patches)."""
    n_patches = measurement.indices.size
    return bool(fit.ok and fit.inlier_count >= settings.min_inlier_fraction * n_patches)


@dataclass(frozen=True, eq=False)
class _PairResult:
    homography: FloatArray
    method: EstimateMethod
    fit: ModelFit
    measurement: PatchMeasurement
    low_confidence: bool


def _prealigned(
    previous_frame: U8Array,
    frame_u8: U8Array,
    grid: PatchGrid,
    settings: YawSettings,
    alignment: GlobalAlignment,
    previous_spectra: PatchSpectra | None,
) -> _PairResult:
    """Patch stage on frame k warped back by the global alignment, composed with it."""
    aligned = warp_into(frame_u8, alignment.matrix, grid.frame_shape)
    before = (
        previous_spectra
        if previous_spectra is not None
        else patch_spectra(previous_frame, grid, None, settings)
    )
    measurement = measure_patches(before, patch_spectra(aligned, grid, before.indices, settings), settings)
    # After a long gap the residual holds the perspective of the tilt change: fit a homography.
    fit = _fit_measurement(grid, measurement, replace(settings, fit_model=settings.prealigned_fit_model))
    if _fit_is_good(fit, measurement, settings):
        low = fit.residual_px > settings.max_residual_px
        return _PairResult(
            alignment.matrix @ fit.homography, EstimateMethod.GLOBAL_PREALIGNED, fit, measurement, low
        )
    if alignment.response >= _MIN_GLOBAL_RESPONSE:
        return _PairResult(alignment.matrix, EstimateMethod.GLOBAL_ONLY, fit, measurement, True)
    return _PairResult(np.eye(3), EstimateMethod.NONE, fit, measurement, True)


def _conclude_pair(
    previous_frame: U8Array,
    frame_u8: U8Array,
    measurement: PatchMeasurement,
    grid: PatchGrid,
    settings: YawSettings,
    previous_spectra: PatchSpectra | None,
    check_global: bool,
) -> _PairResult:
    fit = _fit_measurement(grid, measurement, settings)
    good = _fit_is_good(fit, measurement, settings)
    patches = _PairResult(
        fit.homography, EstimateMethod.PATCHES, fit, measurement, fit.residual_px > settings.max_residual_px
    )
    if good and not check_global:
        return patches
    if _frame_is_flat(previous_frame) or _frame_is_flat(frame_u8):
        logger.debug("flat frame: no yaw")
        return _PairResult(np.eye(3), EstimateMethod.NONE, fit, measurement, True)
    alignment = estimate_global_alignment(previous_frame, frame_u8, settings)
    if good and alignment.response < _MIN_GLOBAL_RESPONSE:
        return patches
    logger.debug(
        "patch fit %s (%d/%d inliers): global pre-alignment",
        "checked" if good else "poor",
        fit.inlier_count,
        measurement.indices.size,
    )
    prealigned = _prealigned(previous_frame, frame_u8, grid, settings, alignment, previous_spectra)
    if good and prealigned.method is not EstimateMethod.GLOBAL_PREALIGNED:
        return patches
    return prealigned


class YawTracker:
    """Integrates the yaw of a frame stream; explicit state in, state out."""

    def __init__(self, settings: YawSettings, grid: PatchGrid) -> None:
        if grid.pyramid_level != settings.pyramid_level or grid.patch_size_px != settings.patch_size_px:
            raise InputError("grid was made with other settings (pyramid level / patch size differ)")
        self.settings = settings
        self.grid = grid

    def _check(self, frame_u8: U8Array, name: str) -> U8Array:
        check_grey_image(frame_u8, name)
        if frame_u8.shape != self.grid.frame_shape:
            raise InputError(f"{name} must have shape {self.grid.frame_shape}, got {frame_u8.shape}")
        return frame_u8

    def initial_state(self, frame0_u8: U8Array, with_spectra: bool = True) -> TrackerState:
        """State at frame 0 (yaw 0); ``with_spectra`` caches its patch spectra for in-process ``track``."""
        frame = self._check(frame0_u8, "frame0_u8")
        spectra = patch_spectra(frame, self.grid, None, self.settings) if with_spectra else None
        return TrackerState(seq=0, yaw_rad=0.0, previous_frame=frame, previous_spectra=spectra)

    def conclude(
        self, state: TrackerState, frame_u8: U8Array, measurement: PatchMeasurement
    ) -> tuple[TrackerState, YawEstimate]:
        """Central stage: fit the measured shifts of frame k, fall back to the global alignment, integrate.

        ``measurement`` may cover any subset of the grid's patches (e.g. when a worker is missing), in
        any order (it is put in ascending index order first, so the fit does not depend on the order).
        The returned state has no spectra; ``track`` adds them.
        """
        frame = self._check(frame_u8, "frame_u8")
        if measurement.indices.size and np.any(np.diff(measurement.indices) <= 0):
            measurement = merge_measurements([measurement])
        if measurement.indices.size and measurement.indices.max() >= self.grid.n_patches:
            raise InputError(f"measurement indices exceed the grid's {self.grid.n_patches} patches")
        result = _conclude_pair(
            state.previous_frame, frame, measurement, self.grid, self.settings, state.previous_spectra, False
        )
        delta = (
            0.0
            if result.method is EstimateMethod.NONE
            else delta_yaw_from_homography_rad(result.homography, self.grid)
        )
        yaw = state.yaw_rad + delta
        estimate = _make_estimate(state.seq + 1, delta, yaw, result)
        return TrackerState(
            seq=state.seq + 1, yaw_rad=yaw, previous_frame=frame, previous_spectra=None
        ), estimate

    def track(self, state: TrackerState, frame_u8: U8Array) -> tuple[TrackerState, YawEstimate]:
        """In-process: spectra of all patches, ``measure_patches`` vs the cached ones, ``conclude``."""
        frame = self._check(frame_u8, "frame_u8")
        previous = state.previous_spectra
        if previous is None:
            previous = patch_spectra(state.previous_frame, self.grid, None, self.settings)
            state = replace(state, previous_spectra=previous)
        current = patch_spectra(frame, self.grid, previous.indices, self.settings)
        measurement = measure_patches(previous, current, self.settings)
        state, estimate = self.conclude(state, frame, measurement)
        return replace(state, previous_spectra=current), estimate


def _make_estimate(seq: int, delta: float, yaw: float, result: _PairResult) -> YawEstimate:
    patch_count = int(result.measurement.indices.size)
    inliers = result.fit.inlier_count if result.method is not EstimateMethod.NONE else 0
    return YawEstimate(
        seq=seq,
        delta_yaw_rad=float(delta),
        yaw_rad=float(yaw),
        inlier_count=inliers,
        patch_count=patch_count,
        valid_count=result.measurement.n_valid,
        confidence=inliers / patch_count if patch_count else 0.0,
        low_confidence=bool(result.low_confidence or result.method is EstimateMethod.NONE),
        method=result.method,
        homography=result.homography,
        residual_px=float(result.fit.residual_px),
    )


def estimate_pair(frame_a: U8Array, frame_b: U8Array, settings: YawSettings) -> YawEstimate:
    """Yaw of one pair a -> b (any rotation): patch fit, checked against and if needed pre-aligned by
    the global Fourier-Mellin estimate."""
    check_grey_image(frame_a, "frame_a")
    check_grey_image(frame_b, "frame_b")
    if frame_a.shape != frame_b.shape:
        raise InputError(
            f"frame_a and frame_b must have the same shape, got {frame_a.shape} and {frame_b.shape}"
        )
    grid = make_patch_grid(frame_a.shape, settings)
    before = patch_spectra(frame_a, grid, None, settings)
    measurement = measure_patches(before, patch_spectra(frame_b, grid, None, settings), settings)
    result = _conclude_pair(frame_a, frame_b, measurement, grid, settings, before, True)
    delta = (
        0.0
        if result.method is EstimateMethod.NONE
        else delta_yaw_from_homography_rad(result.homography, grid)
    )
    return _make_estimate(1, delta, delta, result)
