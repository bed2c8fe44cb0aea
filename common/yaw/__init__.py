"""Yaw from a downward camera by cached-spectrum patch phase correlation (paper A).

Two stages, so a cluster can distribute the first: ``patch_spectra`` / ``measure_patches`` per
patch subset (workers) and ``YawTracker.conclude`` (master); ``YawTracker.track`` composes both.
"""

from common.yaw.correlation import PatchSpectra, measure_patches, patch_spectra, patch_spectra_from_crops
from common.yaw.fit import ModelFit, fit_correspondences, rotation_of_homography_rad, scale_of_homography
from common.yaw.global_align import GlobalAlignment, estimate_global_alignment
from common.yaw.grid import PatchGrid, auto_pyramid_level, for_frame, make_patch_grid
from common.yaw.honest import Provenance, gyro_delta_yaw_rad
from common.yaw.measurement import PatchMeasurement, merge_measurements
from common.yaw.settings import FftBackend, FitModel, YawError, YawSettings
from common.yaw.tracker import (
    EstimateMethod,
    FrameYaw,
    TrackerState,
    YawTracker,
    delta_yaw_from_homography_rad,
    estimate_pair,
)

__all__ = [
    "EstimateMethod",
    "FftBackend",
    "FitModel",
    "FrameYaw",
    "GlobalAlignment",
    "ModelFit",
    "PatchGrid",
    "PatchMeasurement",
    "PatchSpectra",
    "Provenance",
    "TrackerState",
    "YawError",
    "YawSettings",
    "YawTracker",
    "auto_pyramid_level",
    "delta_yaw_from_homography_rad",
    "estimate_global_alignment",
    "estimate_pair",
    "fit_correspondences",
    "for_frame",
    "gyro_delta_yaw_rad",
    "make_patch_grid",
    "measure_patches",
    "merge_measurements",
    "patch_spectra",
    "patch_spectra_from_crops",
    "rotation_of_homography_rad",
    "scale_of_homography",
]
