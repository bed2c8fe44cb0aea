"""Running the particle filter (or the model tracker) along a sequence of frames, and its accuracy against
ground truth.

Used alike by the demo, the benchmark, the tests and (frame by frame) the localizer service, so that the
service's output can be compared with an in-process run.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.geometry import wrap_angle_rad
from common.localization.odometry import Odometry
from common.localization.particle_filter import ParticleFilter, ParticleState, PoseStatistics
from common.localization.pose import rotation_angle_rad
from common.localization.scoring import extract_image_edges
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerState
from common.types import FloatArray


@dataclass(frozen=True)
class TrackResult:
    """Per frame: pose ``means`` (T, 6), ``covariances`` (T, 6, 6), best ``fits`` (T,), ESS (T,)."""

    means: FloatArray
    covariances: FloatArray
    fits: FloatArray
    effective_sample_sizes: FloatArray
    reinitialisations: int


@dataclass(frozen=True)
class TrackAccuracy:
    """Errors after convergence (frames from ``first_frame`` on): RMSE of position (m) and yaw (rad)."""

    position_rmse_m: float
    yaw_rmse_rad: float
    first_frame: int
    position_errors_m: FloatArray
    yaw_errors_rad: FloatArray


def localizer_step(
    pf: ParticleFilter,
    state: ParticleState,
    image: npt.ArrayLike,
    dt_s: float,
    rng: np.random.Generator,
    velocity_world_m_s: npt.ArrayLike | None = None,
    euler_rates_rad_s: npt.ArrayLike | None = None,
) -> tuple[ParticleState, PoseStatistics]:
    """One frame: predict (skipped for ``dt_s == 0``), extract the image's edges, update, estimate."""
    if dt_s > 0.0:
        state = pf.predict(state, dt_s, rng, velocity_world_m_s, euler_rates_rad_s)
    state = pf.update(state, extract_image_edges(image), rng)
    return state, pf.estimate(state)


def track_flight(
    pf: ParticleFilter,
    images: Iterable[npt.ArrayLike],
    times_s: FloatArray,
    guess: npt.ArrayLike,
    rng: np.random.Generator,
    odometry: Odometry | None = None,
) -> TrackResult:
    """Run the filter over frames (one per time stamp), starting from particles spread around ``guess``."""
    state = pf.initialize(guess, rng)
    means, covariances, fits, ess = [], [], [], []
    previous_t: float | None = None
    for i, image in enumerate(images):
        t = float(times_s[i])
        dt = 0.0 if previous_t is None else t - previous_t
        previous_t = t
        velocity = None if odometry is None else odometry.velocities_world_m_s[i]
        rates = None if odometry is None else odometry.euler_rates_rad_s[i]
        state, estimate = localizer_step(pf, state, image, dt, rng, velocity, rates)
        means.append(estimate.mean)
        covariances.append(estimate.covariance)
        fits.append(estimate.best_fit)
        ess.append(estimate.effective_sample_size)
    if not means:
        raise InputError("track_flight needs at least one frame")
    return TrackResult(
        means=np.asarray(means),
        covariances=np.asarray(covariances),
        fits=np.asarray(fits),
        effective_sample_sizes=np.asarray(ess),
        reinitialisations=state.reinitialisations,
    )


def track_model(
    tracker: ModelTracker,
    images: Iterable[npt.ArrayLike],
    times_s: FloatArray,
    state: TrackerState,
    rng: np.random.Generator,
    gyro_rad_s: FloatArray | None = None,
) -> Iterator[TrackerState]:
    """Run the model tracker over frames (one per time stamp) from ``state`` (``tracker.start(pose)``),
    yielding its state after each frame; ``gyro_rad_s``: the camera-frame rate over each frame interval
    (T, 3), row 0 unused. A caller timing the steps times each ``next``."""
    for i, image in enumerate(images):
        dt = 0.0 if i == 0 else float(times_s[i] - times_s[i - 1])
        rate = None if gyro_rad_s is None or i == 0 else gyro_rad_s[i]
        state = tracker.step(state, tracker.edges(image), dt, rng, gyro_rad_s=rate)
        yield state


def pose_errors_mm_deg(
    states: Sequence[TrackerState], p_world_camera_m: FloatArray, R_world_camera: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Position (mm) and rotation (deg) error of each state's pose against the true camera poses of the
    same frames."""
    n = len(states)
    p = np.array([s.pose.p_world_camera_m for s in states]).reshape(n, 3)
    R = np.array([s.pose.R_world_camera for s in states]).reshape(n, 3, 3)
    position_mm = 1e3 * np.linalg.norm(p - p_world_camera_m[:n], axis=1)
    return position_mm, np.degrees(rotation_angle_rad(R, R_world_camera[:n]))


def track_accuracy(estimates: FloatArray, truth: FloatArray, first_frame: int) -> TrackAccuracy:
    """Position and yaw RMSE of (T, 6) estimates against (T, 6) truth over frames ``first_frame`` onwards."""
    if estimates.shape != truth.shape or estimates.ndim != 2 or estimates.shape[1] != 6:
        raise InputError(f"estimates and truth must both be (T, 6), got {estimates.shape} and {truth.shape}")
    if not 0 <= first_frame < estimates.shape[0]:
        raise InputError(f"first_frame must lie in [0, {estimates.shape[0]}), got {first_frame}")
    position_errors = np.linalg.norm(estimates[:, :3] - truth[:, :3], axis=1)
    yaw_errors = wrap_angle_rad(estimates[:, 5] - truth[:, 5])
    return TrackAccuracy(
        position_rmse_m=float(np.sqrt(np.mean(position_errors[first_frame:] ** 2))),
        yaw_rmse_rad=float(np.sqrt(np.mean(yaw_errors[first_frame:] ** 2))),
        first_frame=first_frame,
        position_errors_m=position_errors,
        yaw_errors_rad=yaw_errors,
    )
