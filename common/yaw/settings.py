"""Settings and errors of the yaw core (paper A): one frozen dataclass shared by every stage."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

from common.camera import CameraModel
from common.errors import CapatazError, InputError


class YawError(CapatazError):
    """The yaw core could not produce an estimate (e.g. inconsistent spectra of two streams)."""


class FftBackend(Enum):
    """Who computes the patch transforms; chosen by measurement (``capataz bench yaw`` times both)."""

    OPENCV = "opencv"  # a loop of cv2.dft over the patches (full complex spectrum)
    NUMPY = "numpy"  # one batched numpy.fft.rfft2 over all patches (half spectrum)


class FitModel(Enum):
    """The model fitted to the correspondences patch centre -> centre + shift."""

    SIMILARITY = "similarity"  # rotation + uniform scale + translation (4 dof), the hover model
    HOMOGRAPHY = "homography"  # full plane-induced homography (8 dof)


@dataclass(frozen=True)
class YawSettings:
    """Every tunable of the yaw core; the defaults are the benchmarked configuration.

    The patch grid is laid out on the frame at pyramid level ``pyramid_level`` (each level halves
    the frame with ``cv2.pyrDown``); ``patch_size_px`` is the side of a patch at that level, so a
    patch covers ``patch_size_px * 2**pyramid_level`` full-resolution pixels.
    """

    patch_size_px: int = 32
    grid_cols: int = 8
    grid_rows: int = 5
    margin_px: int = 0  # border left free at full resolution
    pyramid_level: int = 1
    fft_backend: FftBackend = FftBackend.NUMPY
    #: Width (level pixels) of the Gaussian weighting of the cross-power spectrum; the correlation
    #: peak becomes a smooth Gaussian whose 3-point log-parabola fit is the sub-pixel estimate.
    peak_sigma_px: float = 1.0
    #: Tukey window taper of each patch (1 = Hann, 0 = none).
    window_taper: float = 1.0
    #: Exponent of the window-overlap division before the sub-pixel fit (0 = off, 1 = full).
    overlap_correction: float = 2.0
    #: Patches whose grey-level standard deviation (0..255 scale) is below this are textureless.
    min_texture_std: float = 4.0
    #: A patch is valid when its correlation peak exceeds the second peak (outside +-2 px) by this ratio.
    min_peak_ratio: float = 1.5
    fit_model: FitModel = FitModel.SIMILARITY
    #: Model of the patch fit after a global pre-alignment (long gaps: the tilt change's perspective shows).
    prealigned_fit_model: FitModel = FitModel.HOMOGRAPHY
    ransac_threshold_px: float = 1.0  # full-resolution pixels
    ransac_max_iters: int = 500
    min_inliers: int = 6
    #: The patch fit is "poor" (the global pre-alignment runs) below this inlier fraction of valid patches.
    min_inlier_fraction: float = 0.5
    #: Global (Fourier-Mellin) stage: side of the square log-polar input and its number of angle rows.
    global_size_px: int = 256
    global_angle_bins: int = 720
    #: Residual (full-resolution px, median over inliers) above which the estimate is low-confidence.
    max_residual_px: float = 1.5
    #: Above this patch-fit rotation (deg) the patches are measured again on frame k turned back by it (the
    #: window's pull of the shifts towards zero then acts on tiny shifts only); 180 = never.
    refine_min_deg: float = 0.25
    #: Physical limit: a delta implying a faster yaw rate between two stamped frames is refused.
    max_yaw_rate_deg_s: float = 300.0
    #: Physical limit on the yaw acceleration: how far a measured delta may leave the held yaw rate.
    max_yaw_accel_deg_s2: float = 1500.0
    #: A measured delta further than this from the gyro's is not trusted (the gyro bridges the pair).
    gyro_gate_deg: float = 2.0
    #: Standard deviation of the gyro's integrated yaw per second (bias and noise), for the bridge variance.
    gyro_sigma_deg_s: float = 0.5
    #: Global-stage candidates r + k 90 deg whose response reaches this fraction of the best look alike.
    ambiguity_ratio: float = 0.8
    #: Frame period assumed for the held rate when frames carry no stamps.
    frame_period_s: float = 0.05
    #: Intrinsics and lens distortion of the frames (None: an undistorted camera centred on the frame).
    #: Only the central stage uses it (correspondences are undistorted before the fit); not on the wire.
    camera: CameraModel | None = None

    def __post_init__(self) -> None:
        if self.patch_size_px < 8 or self.patch_size_px % 2:
            raise InputError(f"patch_size_px must be an even integer >= 8, got {self.patch_size_px}")
        if self.grid_cols < 1 or self.grid_rows < 1:
            raise InputError(f"grid must be at least 1x1, got {self.grid_cols}x{self.grid_rows}")
        if self.grid_cols * self.grid_rows < 4:
            raise InputError("a grid needs at least 4 patches for a fit")
        if not 0 <= self.pyramid_level <= 4:
            raise InputError(f"pyramid_level must be in 0..4, got {self.pyramid_level}")
        if self.margin_px < 0:
            raise InputError(f"margin_px must be >= 0, got {self.margin_px}")
        if self.peak_sigma_px <= 0.0:
            raise InputError(f"peak_sigma_px must be > 0, got {self.peak_sigma_px}")
        if not 0.0 <= self.window_taper <= 1.0:
            raise InputError(f"window_taper must be in [0, 1], got {self.window_taper}")
        if self.overlap_correction < 0.0 or self.min_texture_std < 0.0 or self.min_peak_ratio < 0.0:
            raise InputError("overlap_correction, min_texture_std and min_peak_ratio must be >= 0")
        if not 0.0 <= self.min_inlier_fraction <= 1.0:
            raise InputError(f"min_inlier_fraction must be in [0, 1], got {self.min_inlier_fraction}")
        if self.ransac_threshold_px <= 0.0 or self.ransac_max_iters < 1 or self.max_residual_px <= 0.0:
            raise InputError("ransac_threshold_px, ransac_max_iters and max_residual_px must be positive")
        if self.min_inliers < 3:
            raise InputError(f"min_inliers must be >= 3, got {self.min_inliers}")
        if self.global_size_px < 64 or self.global_angle_bins < 90:
            raise InputError("global_size_px must be >= 64 and global_angle_bins >= 90")
        limits = (
            self.max_yaw_rate_deg_s,
            self.max_yaw_accel_deg_s2,
            self.gyro_gate_deg,
            self.frame_period_s,
        )
        if not all(math.isfinite(v) and v > 0.0 for v in limits):
            raise InputError(
                "max_yaw_rate_deg_s, max_yaw_accel_deg_s2, gyro_gate_deg and frame_period_s must be positive"
            )
        if not (math.isfinite(self.refine_min_deg) and self.refine_min_deg >= 0.0):
            raise InputError(f"refine_min_deg must be >= 0, got {self.refine_min_deg}")
        if not (math.isfinite(self.gyro_sigma_deg_s) and self.gyro_sigma_deg_s >= 0.0):
            raise InputError(f"gyro_sigma_deg_s must be >= 0, got {self.gyro_sigma_deg_s}")
        if not 0.0 < self.ambiguity_ratio <= 1.0:
            raise InputError(f"ambiguity_ratio must be in (0, 1], got {self.ambiguity_ratio}")
        if self.camera is not None and not isinstance(self.camera, CameraModel):
            raise InputError(f"camera must be a CameraModel, got {type(self.camera).__name__}")

    @property
    def scale(self) -> int:
        """Full-resolution pixels per pixel at the working pyramid level."""
        return int(2**self.pyramid_level)
