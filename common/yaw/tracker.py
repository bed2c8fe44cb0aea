"""The central stage: robust fit, large-rotation fallback and yaw integration (paper A, Algorithm 1).

``YawTracker.track`` is literally ``patch_spectra`` + ``measure_patches`` (the distributable stage)
followed by ``YawTracker.conclude`` (the central stage), so a cluster that runs the first stage on
workers and the second on the master produces the same yaw.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import R_BODY_CAMERA_DOWN, check_rotation_matrix
from common.images import check_grey_image
from common.types import FloatArray, U8Array
from common.yaw.correlation import PatchSpectra, measure_patches, patch_spectra
from common.yaw.fit import rotation_of_homography_rad
from common.yaw.grid import PatchGrid, for_frame, make_patch_grid
from common.yaw.held import MeasuredPair, held_rate, with_measured_pair
from common.yaw.honest import PriorSource, Provenance, make_prior
from common.yaw.level import Levelling, LevelViews
from common.yaw.measurement import PatchMeasurement, merge_measurements
from common.yaw.mount import yaw_per_image_turn
from common.yaw.settings import YawSettings
from common.yaw.stages import EstimateMethod, RefineMeasure, conclude_pair, lens_of
from common.yaw.yaw_variance import YawVariance, add_pair_variance

logger = logging.getLogger(__name__)


__all__ = ["EstimateMethod", "FrameYaw", "TrackerState", "YawTracker", "estimate_pair"]


@dataclass(frozen=True, eq=False)
class FrameYaw:
    """Yaw of frame ``seq`` relative to frame ``seq - 1`` and integrated since frame 0.

    ``delta_yaw_rad`` is the change of the vehicle's yaw (ZYX yaw of q_world_body, CCW seen from above)
    that was *integrated* (the image's turn times the mount's :func:`~common.yaw.mount.yaw_per_image_turn`,
    1 for ``R_BODY_CAMERA_DOWN``): the measured one when
    ``provenance`` is ``MEASURED``, else the gyro's (``BRIDGED``) or the held rate's (``HELD``);
    ``measured_delta_rad`` is what the camera stage measured (NaN when nothing). ``homography`` (3, 3) maps
    frame seq-1 pixels to frame seq pixels (undistorted pixels when the settings carry a lens model).
    ``confidence`` in [0, 1] is the inlier fraction of the measured patches. ``yaw_variance_rad2`` is the
    variance of ``yaw_rad`` (it grows with every pair, fastest while bridging or holding; a measured or held
    pair adds its covariance with the ones before, :func:`~common.yaw.yaw_variance.add_pair_variance`).
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
    provenance: Provenance = Provenance.MEASURED
    measured_delta_rad: float = math.nan
    delta_variance_rad2: float = 0.0
    yaw_variance_rad2: float = 0.0


@dataclass(frozen=True, eq=False)
class TrackerState:
    """Explicit tracker state: the last frame (needed only by the fallbacks), in-process its spectra, and
    what the honest integration needs (stamp, the recent measured pairs whose robust rate is held over
    untrusted pairs without a gyro (:mod:`common.yaw.held`), time since the last measured pair, the yaw's
    variance with what its next pair's covariance needs: :func:`~common.yaw.yaw_variance.add_pair_variance`).

    Frames are kept by reference: callers must not modify a frame after passing it in.
    """

    seq: int
    yaw_rad: float
    previous_frame: U8Array
    previous_spectra: PatchSpectra | None
    stamp_s: float | None = None
    measured_pairs: tuple[MeasuredPair, ...] = ()
    since_measured_s: float = 0.0
    yaw_variance: YawVariance = field(default_factory=YawVariance)
    #: the previous frame's tilt (``R_level_body``, :mod:`common.yaw.level`), None when not known
    R_level_body: FloatArray | None = None

    @property
    def yaw_variance_rad2(self) -> float:
        return self.yaw_variance.variance_rad2


def delta_yaw_from_homography_rad(homography: FloatArray, grid: PatchGrid) -> float:
    """Vehicle yaw change from the image homography of a downward camera (``rotation_of_homography_rad``).

    With ``R_BODY_CAMERA_DOWN`` (image x = body -y, image y = body -x, optical axis = body -z) a yaw of
    +psi (CCW from above) turns the image content by +psi in the image's (x right, y down) axes.
    Evaluated at the frame centre.
    """
    height, width = grid.frame_shape
    return rotation_of_homography_rad(homography, ((width - 1) / 2.0, (height - 1) / 2.0))


class YawTracker:
    """Integrates the yaw of a frame stream; explicit state in, state out.

    Each frame is checked once, where it enters (:meth:`initial_state`, :meth:`conclude`, :meth:`track`);
    the stages after that trust it.
    """

    def __init__(
        self, settings: YawSettings, grid: PatchGrid, R_body_camera: npt.ArrayLike = R_BODY_CAMERA_DOWN
    ) -> None:
        settings = for_frame(settings, grid.frame_shape)
        if grid.pyramid_level != settings.level or grid.patch_size_px != settings.patch_size_px:
            raise InputError("grid was made with other settings (pyramid level / patch size differ)")
        R_bc = check_rotation_matrix(R_body_camera, "R_body_camera")
        #: the vehicle's yaw per radian the image turns about minus the optical axis (1: the down mount)
        self.yaw_per_turn = yaw_per_image_turn(R_bc)
        #: a camera mounted off the down mount, with intrinsics: the correspondences are fitted in the view of
        #: a virtual down camera, where a yaw is a turn about the centre (a tilted view of the floor turns
        #: with a translation too); without intrinsics the image's turn is scaled to the yaw
        self.nadir_view = settings.camera is not None and not np.allclose(R_bc, R_BODY_CAMERA_DOWN, atol=1e-9)
        R_nadir_camera = R_BODY_CAMERA_DOWN.T @ R_bc if self.nadir_view else None
        self.settings = settings
        self.grid = grid
        self.lens = lens_of(grid, settings, R_nadir_camera)
        camera = self.lens.camera
        #: the level views of frames whose tilt is given (a lens with intrinsics only)
        self._level_views = None if camera is None else LevelViews(camera.K, R_bc)
        self._n_patches = grid.n_patches

    def initial_state(
        self,
        frame0_u8: U8Array,
        with_spectra: bool = True,
        stamp_s: float | None = None,
        yaw_rad: float = 0.0,
        yaw_variance_rad2: float = 0.0,
        R_level_body: npt.ArrayLike | None = None,
    ) -> TrackerState:
        """State at frame 0; ``with_spectra`` caches its patch spectra for in-process ``track``. A stream
        that continues a yaw (a new rig, a take-over) starts from it and its variance (the memories of the
        pairs before start over); ``R_level_body`` is frame 0's tilt (:meth:`conclude`)."""
        frame = check_grey_image(frame0_u8, "frame0_u8", shape=self.grid.frame_shape)
        if not math.isfinite(yaw_rad):
            raise InputError(f"need a finite yaw, got {yaw_rad}")
        spectra = patch_spectra(frame, self.grid, None, self.settings) if with_spectra else None
        return TrackerState(
            seq=0, yaw_rad=yaw_rad, previous_frame=frame, previous_spectra=spectra,
            stamp_s=_check_stamp(stamp_s), yaw_variance=YawVariance(yaw_variance_rad2),
            R_level_body=_check_tilt(R_level_body),
        )  # fmt: skip

    def conclude(
        self,
        state: TrackerState,
        frame_u8: U8Array,
        measurement: PatchMeasurement,
        stamp_s: float | None = None,
        gyro_delta_rad: float | None = None,
        refine_measure: RefineMeasure | None = None,
        R_level_body: npt.ArrayLike | None = None,
    ) -> tuple[TrackerState, FrameYaw]:
        """Central stage: fit the measured shifts of frame k, fall back if untrusted, integrate honestly.

        ``measurement`` may cover any subset of the grid's patches (e.g. when a worker is missing), in
        any order (it is put in ascending index order first, so the fit does not depend on the order).
        ``stamp_s`` (frame k's time) enables the physical rate limit; ``gyro_delta_rad`` (the gyro's
        rotation since frame k-1, :func:`~common.yaw.honest.gyro_delta_yaw_rad`) is the prior and the
        bridge over untrusted pairs; ``refine_measure`` measures a turning pair's second pass elsewhere (a
        master: on its members, :data:`~common.yaw.stages.RefineMeasure`). ``R_level_body`` is frame k's
        tilt (:func:`~common.yaw.level.R_level_body_of_up`): when the previous frame's is known too (and the
        lens's intrinsics), the pair is fitted in the two frames' level views and measures the heading's
        change (:mod:`common.yaw.level`). The returned state has no spectra; ``track`` adds them.
        """
        tilt = _check_tilt(R_level_body)
        frame = check_grey_image(frame_u8, "frame_u8", shape=self.grid.frame_shape)
        return self._conclude(state, frame, measurement, stamp_s, gyro_delta_rad, False, refine_measure, tilt)

    def _conclude(
        self,
        state: TrackerState,
        frame: U8Array,
        measurement: PatchMeasurement,
        stamp_s: float | None,
        gyro_delta_rad: float | None,
        check_global: bool,
        refine_measure: RefineMeasure | None = None,
        R_level_body: FloatArray | None = None,
    ) -> tuple[TrackerState, FrameYaw]:
        """:meth:`conclude` of a checked frame; ``check_global`` verifies even a trusted patch fit against the
        global stage (one pair of any rotation, :func:`estimate_pair`)."""
        stamp = _check_stamp(stamp_s)
        levelling = self._levelling(state.R_level_body, R_level_body)
        if gyro_delta_rad is not None and not math.isfinite(gyro_delta_rad):
            raise InputError(f"gyro_delta_rad must be finite, got {gyro_delta_rad}")
        if measurement.indices.size and np.any(np.diff(measurement.indices) <= 0):
            measurement = merge_measurements([measurement])
        if measurement.indices.size and measurement.indices.max() >= self._n_patches:
            raise InputError(f"measurement indices exceed the grid's {self._n_patches} patches")
        dt = stamp - state.stamp_s if stamp is not None and state.stamp_s is not None else None
        if dt is not None and dt <= 0.0:
            raise InputError(f"frame stamps must increase, got {state.stamp_s} then {stamp}")
        held = held_rate(state.measured_pairs)
        # the measured view's turn is the yaw's in a nadir or level view, else the image's turn
        yaw_view = self.nadir_view or levelling is not None
        # the gyro's turn about minus the optical axis, in the measured view's units (the nadir view: yaw)
        k_in = self.yaw_per_turn if yaw_view else 1.0
        gyro = None if gyro_delta_rad is None else k_in * gyro_delta_rad
        prior = make_prior(self.settings, dt, gyro, held, state.since_measured_s)
        result = conclude_pair(
            state.previous_frame, frame, measurement, self.grid, self.lens, self.settings,
            state.previous_spectra, prior, check_global, refine_measure, levelling,
        )  # fmt: skip
        step_s = dt if dt is not None else self.settings.frame_period_s
        # the pair's end on the stamps' clock, or on a nominal one (frame periods) for unstamped frames
        stop_s = (
            stamp if dt is not None and stamp is not None else (state.seq + 1) * self.settings.frame_period_s
        )
        pairs = state.measured_pairs
        if result.trusted:
            provenance, delta, variance = Provenance.MEASURED, result.delta_rad, result.variance_rad2
        elif prior.source is PriorSource.GYRO:
            # the gyro measured this pair: its rate is as good as the camera's for a later hold
            provenance, delta, variance = Provenance.BRIDGED, prior.delta_rad, prior.variance_rad2
        else:
            provenance, delta, variance = Provenance.HELD, prior.delta_rad, prior.variance_rad2
        since = state.since_measured_s + step_s if provenance is Provenance.HELD else 0.0
        if provenance is not Provenance.HELD:
            pair = MeasuredPair(stop_s, step_s, delta)
            # a pair not after the window's newest (the stream switched between stamped and unstamped
            # frames) starts the window over
            restart = bool(pairs) and pair.stop_s <= pairs[-1].stop_s
            pairs = (pair,) if restart else with_measured_pair(pairs, pair)
        # the measured view's turn (measured, or the gyro's about the same axis) as the vehicle's yaw
        k = 1.0 if yaw_view else self.yaw_per_turn
        delta, variance = k * delta, k * k * variance
        yaw = state.yaw_rad + delta
        yaw_variance = add_pair_variance(state.yaw_variance, variance, step_s, provenance)
        measured = result.method is not EstimateMethod.NONE
        patch_count = int(result.measurement.indices.size)
        inliers = result.fit.inlier_count if measured else 0
        estimate = FrameYaw(
            seq=state.seq + 1,
            delta_yaw_rad=float(delta),
            yaw_rad=float(yaw),
            inlier_count=inliers,
            patch_count=patch_count,
            valid_count=result.measurement.n_valid,
            confidence=inliers / patch_count if patch_count else 0.0,
            low_confidence=bool(result.low_confidence or provenance is not Provenance.MEASURED),
            method=result.method,
            homography=result.homography,
            residual_px=float(result.fit.residual_px),
            provenance=provenance,
            measured_delta_rad=float(k * result.delta_rad) if measured else math.nan,
            delta_variance_rad2=float(variance),
            yaw_variance_rad2=yaw_variance.variance_rad2,
        )
        return TrackerState(
            seq=state.seq + 1,
            yaw_rad=yaw,
            previous_frame=frame,
            previous_spectra=None,
            stamp_s=stamp,
            measured_pairs=pairs,
            since_measured_s=since,
            yaw_variance=yaw_variance,
            R_level_body=R_level_body,
        ), estimate

    def _levelling(self, before: FloatArray | None, after: FloatArray | None) -> Levelling | None:
        """The pair's level views when both frames' tilts and the lens's intrinsics are known."""
        if before is None or after is None or self._level_views is None:
            return None
        return self._level_views.pair(before, after)

    def track(
        self,
        state: TrackerState,
        frame_u8: U8Array,
        stamp_s: float | None = None,
        gyro_delta_rad: float | None = None,
        R_level_body: npt.ArrayLike | None = None,
    ) -> tuple[TrackerState, FrameYaw]:
        """In-process: spectra of all patches, ``measure_patches`` vs the cached ones, ``conclude``."""
        tilt = _check_tilt(R_level_body)
        frame = check_grey_image(frame_u8, "frame_u8", shape=self.grid.frame_shape)
        previous = state.previous_spectra
        if previous is None:
            previous = patch_spectra(state.previous_frame, self.grid, None, self.settings)
            state = replace(state, previous_spectra=previous)
        current = patch_spectra(frame, self.grid, previous.indices, self.settings)
        measurement = measure_patches(previous, current, self.settings)
        state, estimate = self._conclude(
            state, frame, measurement, stamp_s, gyro_delta_rad, False, None, tilt
        )
        return replace(state, previous_spectra=current), estimate


def _check_tilt(R_level_body: npt.ArrayLike | None) -> FloatArray | None:
    return None if R_level_body is None else check_rotation_matrix(R_level_body, "R_level_body")


def _check_stamp(stamp_s: float | None) -> float | None:
    if stamp_s is not None and not math.isfinite(stamp_s):
        raise InputError(f"stamp_s must be finite, got {stamp_s}")
    return None if stamp_s is None else float(stamp_s)


def estimate_pair(
    frame_a: U8Array, frame_b: U8Array, settings: YawSettings, gyro_delta_rad: float | None = None
) -> FrameYaw:
    """Yaw of one pair a -> b (any rotation): patch fit, checked against and if needed pre-aligned by
    the global Fourier-Mellin estimate; ``gyro_delta_rad`` disambiguates look-alike rotations. Without a
    trusted measurement the delta is the prior's (0 without a gyro) and the estimate is not MEASURED."""
    a = check_grey_image(frame_a, "frame_a")
    b = check_grey_image(frame_b, "frame_b")
    if a.shape != b.shape:
        raise InputError(f"frame_a and frame_b must have the same shape, got {a.shape} and {b.shape}")
    settings = for_frame(settings, a.shape)
    grid = make_patch_grid(a.shape, settings)
    tracker = YawTracker(settings, grid)
    before = patch_spectra(a, grid, None, settings)
    state = TrackerState(seq=0, yaw_rad=0.0, previous_frame=a, previous_spectra=before)
    measurement = measure_patches(before, patch_spectra(b, grid, None, settings), settings)
    return tracker._conclude(state, b, measurement, None, gyro_delta_rad, True)[1]
