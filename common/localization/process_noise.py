"""The model tracker's process noise, in the units that matter: pixels of image motion per frame.

One home for how much the particles spread between frames (the settings are :class:`NoiseSettings`, the
state :class:`NoiseState`). What the scoring can see is image motion, so the noise is set there and turned
into pose units through the scene and the stream:

- **Scene**: a model ``d`` metres away (median depth of its points in view) seen with focal length ``f``
  px, of radius ``R`` (half its bounding-box diagonal) appears ``r = f R / d`` px in radius (clamped to
  [``MIN_APPARENT_RADIUS_PX``, half the image diagonal]). One pixel of image motion is a sideways move of
  ``d / f`` m, a move along the optical axis of ``d / r`` m (the outline grows by a pixel), a turn about the
  image axes of ``1 / f`` rad and a roll about the optical axis of ``1 / r`` rad
  (:func:`pixel_scale`). Each axis of the particles' noise moves the outline by ``noise_px``.
- **Stream**: the frame interval is measured from the stamps (a running mean that a skipped frame does not
  enter, :func:`observe_interval`); a frame ``k`` intervals after the last one is predicted with
  ``k x noise_px`` (up to ``max_gap_frames``): a skipped frame widens the prediction by the elapsed time.
- **Online**: after every good frame the motion model's residual -- the RMS image displacement of the
  model's edge centres between the predicted pose and the refined one, per frame interval
  (:func:`residual_px`) -- enters a running mean of squares; ``noise_px = gain x`` its root, within
  [``floor_px``, ``ceiling_px``] (:func:`adapt`). A steady camera gets a tight cloud, a shaking one a wide
  one, whatever its size, distance, lens or frame rate.
- **Bounds per second**: the ceiling is stated at ``reference_rate_hz`` and grows with a longer frame
  interval (:func:`ceiling_px`): at 5 fps the office's fast flight moves the image 40-50 px per frame, six
  times what the same motion does at 30 fps. It also bounds the motion model's velocity uncertainty when it
  starts (after a search, :meth:`~common.localization.tracker_views.TrackerViews.start_rates`) and which
  move from the last good pose a search's pose may take for a velocity (a search fixes the pose, not the
  motion: the tracker starts moving as the camera did since the last good pose when that is recent).

The explicit options (``velocity_noise_m_s``, ``angular_noise_rad_s`` of the tracker's settings;
``--velocity-noise`` / ``--angular-noise``) override the derived noise per frame-interval-second, as before.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from common.bounds import Bounded, bounded
from common.camera import CameraModel
from common.localization.pose import CameraPose
from common.types import FloatArray

#: a model seen smaller than this (px radius) is scaled as if this big (depth and roll stay bounded)
MIN_APPARENT_RADIUS_PX = 20.0


@dataclass(frozen=True)
class NoiseSettings(Bounded):
    """Process noise in image pixels per frame (see the module docstring)."""

    #: expected unmodelled image motion per frame before any has been measured (px)
    initial_px: float = bounded(2.0, gt=0.0)
    floor_px: float = bounded(0.75, gt=0.0)
    ceiling_px: float = bounded(8.0, gt=0.0)
    #: noise = gain x the running RMS residual (px per frame)
    gain: float = bounded(1.5, gt=0.0)
    #: weight of the newest frame in the running means (residual, frame interval)
    memory: float = bounded(0.2, gt=0.0, le=1.0)
    #: a gap of more frames than this widens the prediction no further
    max_gap_frames: float = bounded(8.0, ge=1.0)
    #: the frame rate ``ceiling_px`` is stated at: a camera's motion is bounded per second, not per frame, so
    #: a longer frame interval raises the ceiling in proportion (:func:`ceiling_px`)
    reference_rate_hz: float = bounded(30.0, gt=0.0)


@dataclass(frozen=True)
class NoiseState:
    """The adapted noise (px per frame), the running mean square residual and the frame interval (s)."""

    noise_px: float
    mean_square_px2: float
    frame_interval_s: float | None = None
    #: frame intervals the last step spanned (see :func:`observe_interval`)
    last_frames: float = 1.0

    @classmethod
    def initial(cls, settings: NoiseSettings) -> NoiseState:
        px = settings.initial_px
        return cls(px, (px / settings.gain) ** 2, None)


@dataclass(frozen=True)
class PixelScale:
    """Pose units per pixel of image motion: sideways and along the axis (m), turn and roll (rad)."""

    lateral_m: float
    depth_m: float
    turn_rad: float
    roll_rad: float

    def sigmas(self, px: float) -> tuple[FloatArray, FloatArray]:
        """Camera-frame standard deviations (position m (3,), rotation rad (3,)) moving the image ``px``."""
        return (
            px * np.array([self.lateral_m, self.lateral_m, self.depth_m]),
            px * np.array([self.turn_rad, self.turn_rad, self.roll_rad]),
        )


def pixel_scale(distance_m: float, camera: CameraModel, model_radius_m: float) -> PixelScale:
    """What one pixel of image motion is in pose units for a model ``distance_m`` away."""
    f = 0.5 * (camera.fx + camera.fy)
    d = max(float(distance_m), 1e-6)
    half_diagonal = 0.5 * float(np.hypot(camera.width, camera.height))
    radius_px = float(np.clip(f * model_radius_m / d, MIN_APPARENT_RADIUS_PX, half_diagonal))
    return PixelScale(lateral_m=d / f, depth_m=d / radius_px, turn_rad=1.0 / f, roll_rad=1.0 / radius_px)


def observe_interval(state: NoiseState, dt_s: float, settings: NoiseSettings) -> NoiseState:
    """The state with ``dt_s`` in its frame interval (unless it is a gap of 1.5 intervals or more) and the
    frames this step spans in ``last_frames`` (``dt_s`` over the interval, at most ``max_gap_frames``; 0 for
    ``dt_s <= 0``; 1 for the first interval)."""
    interval = state.frame_interval_s
    if dt_s <= 0.0:
        frames = 0.0
    elif interval is None:
        interval, frames = dt_s, 1.0
    else:
        frames = float(min(dt_s / interval, settings.max_gap_frames))
        if dt_s < 1.5 * interval:
            interval = (1.0 - settings.memory) * interval + settings.memory * dt_s
    return replace(state, frame_interval_s=interval, last_frames=frames)


def residual_px(
    predicted: CameraPose, measured: CameraPose, points_world_m: FloatArray, camera: CameraModel
) -> float:
    """Robust RMS image displacement (px: the root of the median square) of ``points_world_m`` (N, 3)
    between two poses, over the points in the image at the predicted pose and in front of both cameras at
    no less than a fifth of their median depth (pinhole; 0 when there is none): a camera inside its model
    (a room) does not count the points beside, behind or right in front of it."""
    uv, depth = [], []
    for pose in (predicted, measured):
        X = (points_world_m - pose.p_world_camera_m) @ pose.R_world_camera
        z = np.maximum(X[:, 2], 1e-9)
        uv.append(np.stack([camera.fx * X[:, 0] / z + camera.cx, camera.fy * X[:, 1] / z + camera.cy], 1))
        depth.append(X[:, 2])
    u, v = uv[0][:, 0], uv[0][:, 1]
    ok = (depth[0] > 1e-6) & (depth[1] > 1e-6)
    ok &= (u >= 0.0) & (u < camera.width) & (v >= 0.0) & (v < camera.height)
    if not ok.any():
        return 0.0
    near = 0.2 * float(np.median(depth[0][ok]))
    ok &= (depth[0] >= near) & (depth[1] >= near)
    return float(np.sqrt(np.median(np.sum((uv[0][ok] - uv[1][ok]) ** 2, axis=1))))


def ceiling_px(settings: NoiseSettings, frame_interval_s: float | None) -> float:
    """The largest expected image motion per frame (px): ``ceiling_px`` at ``reference_rate_hz`` or faster,
    in proportion to the frame interval beyond it (unknown interval: the reference's)."""
    reference_s = 1.0 / settings.reference_rate_hz
    return settings.ceiling_px * max(1.0, (frame_interval_s or reference_s) / reference_s)


def adapt(state: NoiseState, residual_per_frame_px: float, settings: NoiseSettings) -> NoiseState:
    """The noise after a good frame whose motion-model residual was ``residual_per_frame_px``."""
    ceiling = ceiling_px(settings, state.frame_interval_s)
    r = min(float(residual_per_frame_px), ceiling / settings.gain * 2.0)  # one outlier is bounded
    ms = (1.0 - settings.memory) * state.mean_square_px2 + settings.memory * r * r
    px = float(np.clip(settings.gain * np.sqrt(ms), settings.floor_px, ceiling))
    return replace(state, noise_px=px, mean_square_px2=ms)
