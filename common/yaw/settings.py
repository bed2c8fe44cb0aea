"""Settings and errors of the yaw core (paper A): one frozen dataclass shared by every stage."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import Enum

from common.bounds import Bounded, bounded
from common.camera import CameraModel
from common.errors import CapatazError, InputError


class YawError(CapatazError):
    """The yaw core could not produce an estimate (e.g. inconsistent spectra of two streams)."""


class FftBackend(Enum):
    """Who computes the patch transforms; chosen by measurement (``capataz bench fft`` and ``capataz bench
    yaw`` time each)."""

    OPENCV = "opencv"  # a loop of cv2.dft over the patches (full complex spectrum)
    NUMPY = "numpy"  # one batched numpy.fft.rfft2 over all patches (half spectrum; forward in double)
    SCIPY = "scipy"  # one batched scipy.fft.rfft2 over all patches (half spectrum, single precision)


class FitModel(Enum):
    """The model fitted to the correspondences patch centre -> centre + shift."""

    SIMILARITY = "similarity"  # rotation + uniform scale + translation (4 dof), the hover model
    HOMOGRAPHY = "homography"  # full plane-induced homography (8 dof)


@dataclass(frozen=True)
class YawSettings(Bounded):
    """Every tunable of the yaw core; the defaults are the benchmarked configuration.

    The bounds are also the wire's: :class:`~common.wire.messages.YawJobSettings` is generated from these
    fields (each count and size a member allocates windows and spectra by is bounded above here).

    The patch grid is laid out on the frame at pyramid level ``pyramid_level`` (each level halves
    the frame with ``cv2.pyrDown``); ``patch_size_px`` is the side of a patch at that level, so a
    patch covers ``patch_size_px * 2**pyramid_level`` full-resolution pixels. By default (None) the level
    follows the frame's size (:func:`~common.yaw.grid.auto_pyramid_level`: level 1 up to 752x480, where the
    defaults were measured; 1280x720 at 2, 1920x1080 at 3), the pixel thresholds with it; the grid and the
    tracker work with the settings resolved for their frames (:func:`~common.yaw.grid.for_frame`).
    """

    patch_size_px: int = bounded(32, ge=8, le=256, help="patch side at the pyramid level")
    grid_cols: int = bounded(8, ge=1, le=64, help="patch grid columns")
    grid_rows: int = bounded(5, ge=1, le=64, help="patch grid rows")
    margin_px: int = bounded(0, ge=0, le=4096)  # border left free at full resolution
    pyramid_level: int | None = bounded(
        None, ge=0, le=4, optional=True, help="pyramid level of the patches (default: by the frame's size)"
    )
    fft_backend: FftBackend = FftBackend.SCIPY
    #: Width (level pixels) of the Gaussian weighting of the cross-power spectrum; the correlation
    #: peak becomes a smooth Gaussian whose 3-point log-parabola fit is the sub-pixel estimate.
    peak_sigma_px: float = bounded(1.0, ge=1e-3, le=64.0)
    #: Tukey window taper of each patch (1 = Hann, 0 = none).
    window_taper: float = bounded(1.0, ge=0.0, le=1.0)
    #: Exponent of the window-overlap division before the sub-pixel fit (0 = off, 1 = full).
    overlap_correction: float = bounded(2.0, ge=0.0, le=8.0)
    #: Patches whose grey-level standard deviation (0..255 scale) is below this are textureless.
    min_texture_std: float = bounded(4.0, ge=0.0, le=255.0)
    #: A patch is valid when its correlation peak exceeds the second peak (outside +-2 px) by this ratio.
    min_peak_ratio: float = bounded(1.5, ge=0.0, le=1e3)
    fit_model: FitModel = FitModel.SIMILARITY
    #: Model of the patch fit after a global pre-alignment (long gaps: the tilt change's perspective shows).
    prealigned_fit_model: FitModel = FitModel.HOMOGRAPHY
    ransac_threshold_px: float = bounded(1.0, ge=1e-3, le=1e3)  # full-resolution pixels
    ransac_max_iters: int = bounded(500, ge=1, le=10_000)
    min_inliers: int = bounded(6, ge=3, le=4096)
    #: The patch fit is "poor" (the global pre-alignment runs) below this inlier fraction of valid patches.
    min_inlier_fraction: float = bounded(0.5, ge=0.0, le=1.0)
    #: Global (Fourier-Mellin) stage: side of the square log-polar input and its number of angle rows.
    global_size_px: int = bounded(256, ge=64, le=1024)
    global_angle_bins: int = bounded(720, ge=90, le=4096)
    #: Residual (full-resolution px, median over inliers) above which the estimate is low-confidence.
    max_residual_px: float = bounded(1.5, ge=1e-3, le=1e3)
    #: Above this patch-fit rotation (deg) the patches are measured again on frame k turned back by it (the
    #: window's pull of the shifts towards zero then acts on tiny shifts only); 180 = never.
    refine_min_deg: float = bounded(0.25, ge=0.0, le=180.0)
    #: The refinement measures at most this many patches: every k-th column and row of the grid, k the
    #: smallest step that keeps within it. It corrects a bias of a few % of the turn, so a spread sub-grid
    #: is enough; on a large grid a full second pass doubled a turning frame's cost, and on the distributed
    #: path the master pays it alone (:func:`common.yaw.stages.refine_indices`). The default grid (40)
    #: refines every patch.
    refine_max_patches: int = bounded(48, ge=8, le=4096)
    #: Physical limit: a delta implying a faster yaw rate between two stamped frames is refused.
    max_yaw_rate_deg_s: float = bounded(
        300.0, gt=0.0, le=1e5, help="physical yaw-rate limit in deg/s: deltas implying more are refused"
    )
    #: Physical limit on the yaw acceleration: how far a measured delta may leave the held yaw rate.
    max_yaw_accel_deg_s2: float = bounded(1500.0, gt=0.0, le=1e7)
    #: A measured delta further than this from the gyro's is not trusted (the gyro bridges the pair).
    gyro_gate_deg: float = bounded(2.0, gt=0.0, le=180.0)
    #: The gyro's yaw-rate bias left after calibration (1 sigma, deg/s) and its white-noise density
    #: (deg/s/sqrt(Hz)): a bridged pair of gap dt has the variance ``(bias dt)^2 + density^2 dt``. The
    #: defaults are the simulated MEMS gyro's (MPU-6000 class, :mod:`common.sim.sensors`); set your IMU's.
    gyro_sigma_deg_s: float = bounded(0.3, ge=0.0, le=1e3, help="gyro yaw-rate bias, 1 sigma (deg/s)")
    gyro_noise_deg_s_rthz: float = bounded(
        0.005, ge=0.0, le=1e3, help="gyro white-noise density (deg/s/sqrt(Hz))"
    )
    #: Global-stage candidates r + k 90 deg whose response reaches this fraction of the best look alike.
    ambiguity_ratio: float = bounded(0.8, gt=0.0, le=1.0)
    #: Frame period assumed for the held rate when frames carry no stamps.
    frame_period_s: float = bounded(0.05, gt=0.0, le=60.0)
    #: Intrinsics and lens distortion of the frames (None: an undistorted camera centred on the frame).
    #: Only the central stage uses it (correspondences are undistorted before the fit); not on the wire.
    camera: CameraModel | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.patch_size_px % 2:
            raise InputError(f"patch_size_px must be an even integer >= 8, got {self.patch_size_px}")
        if self.grid_cols * self.grid_rows < 4:
            raise InputError("a grid needs at least 4 patches for a fit")
        if self.camera is not None and not isinstance(self.camera, CameraModel):
            raise InputError(f"camera must be a CameraModel, got {type(self.camera).__name__}")

    @functools.cached_property
    def scale(self) -> int:
        """Full-resolution pixels per pixel at the working pyramid level (computed once per settings)."""
        return int(2**self.level)

    @property
    def level(self) -> int:
        """The working pyramid level; settings whose level follows the frame's size must be resolved for a
        frame first (:func:`~common.yaw.grid.for_frame`)."""
        if self.pyramid_level is None:
            raise InputError("pyramid_level follows the frame's size: resolve the settings for a frame first")
        return self.pyramid_level
