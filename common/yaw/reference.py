"""Paper A's exact method, kept as the benchmark baseline and a cross-check of the core.

Paper A, Algorithms 1-2: ``cv2.phaseCorrelate`` per patch pair at full resolution (both spectra
recomputed every frame), patch centre -> centre + shift, RANSAC homography, psi from it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from common.errors import InputError
from common.images import check_grey_image
from common.types import FloatArray, U8Array
from common.yaw.fit import ModelFit, fit_correspondences
from common.yaw.grid import PatchGrid, make_patch_grid
from common.yaw.settings import FitModel, YawSettings
from common.yaw.tracker import delta_yaw_from_homography_rad

#: The paper's fit: a homography through RANSAC.
REFERENCE_FIT_MODEL = FitModel.HOMOGRAPHY


def reference_settings(patch_size_px: int = 64, grid_cols: int = 8, grid_rows: int = 5) -> YawSettings:
    """Settings of the reference: full resolution, ``patch_size_px`` patches, homography fit."""
    return YawSettings(
        patch_size_px=patch_size_px,
        grid_cols=grid_cols,
        grid_rows=grid_rows,
        pyramid_level=0,
        fit_model=REFERENCE_FIT_MODEL,
    )


@functools.lru_cache(maxsize=8)
def _window64(size_px: int) -> FloatArray:
    window = np.asarray(cv2.createHanningWindow((size_px, size_px), cv2.CV_64F), dtype=np.float64)
    window.setflags(write=False)
    return window


@dataclass(frozen=True, eq=False)
class ReferencePair:
    """Result of the reference method on one pair: shifts (P, 2), responses (P,), fit and delta yaw."""

    shift_px: FloatArray
    response: FloatArray
    fit: ModelFit
    delta_yaw_rad: float


def reference_shifts(frame_a: U8Array, frame_b: U8Array, grid: PatchGrid) -> tuple[FloatArray, FloatArray]:
    """``cv2.phaseCorrelate`` of every patch pair (Hann window): shifts (P, 2) [dx, dy] and responses (P,)."""
    level_a = grid.level_image(check_grey_image(frame_a, "frame_a", shape=grid.frame_shape))
    level_b = grid.level_image(check_grey_image(frame_b, "frame_b", shape=grid.frame_shape))
    window = _window64(grid.patch_size_px)
    scale = float(2**grid.pyramid_level)
    shifts = np.empty((grid.n_patches, 2))
    responses = np.empty(grid.n_patches)
    for i in range(grid.n_patches):
        rows, cols = grid.slices(i)
        patch_a = level_a[rows, cols].astype(np.float64)
        patch_b = level_b[rows, cols].astype(np.float64)
        (dx, dy), response = cv2.phaseCorrelate(patch_a, patch_b, window)
        shifts[i] = (dx * scale, dy * scale)
        responses[i] = response
    return shifts, responses


def reference_pair(
    frame_a: U8Array, frame_b: U8Array, grid: PatchGrid, settings: YawSettings
) -> ReferencePair:
    """The paper's method on one pair a -> b (no pre-alignment, no texture rejection)."""
    check_grey_image(frame_a, "frame_a")
    check_grey_image(frame_b, "frame_b")
    if frame_a.shape != frame_b.shape:
        raise InputError(f"frames must have the same shape, got {frame_a.shape} and {frame_b.shape}")
    shifts, responses = reference_shifts(frame_a, frame_b, grid)
    fit = fit_correspondences(grid.centres_px, grid.centres_px + shifts, settings)
    delta = delta_yaw_from_homography_rad(fit.homography, grid) if fit.ok else 0.0
    return ReferencePair(shift_px=shifts, response=responses, fit=fit, delta_yaw_rad=delta)


def reference_yaw_series(frames: list[U8Array], settings: YawSettings | None = None) -> FloatArray:
    """Integrated yaw (M,) of a frame list by the reference method (frame 0 has yaw 0)."""
    if not frames:
        raise InputError("frames must not be empty")
    chosen = settings if settings is not None else reference_settings()
    grid = make_patch_grid(frames[0].shape, chosen)
    yaw = np.zeros(len(frames))
    for k in range(1, len(frames)):
        yaw[k] = yaw[k - 1] + reference_pair(frames[k - 1], frames[k], grid, chosen).delta_yaw_rad
    return yaw
