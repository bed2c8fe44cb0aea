"""The localizer's two estimators behind one interface: ``step(frame, dt_s, vo) -> PoseEstimate``.

- :class:`ParticleFilterPath`: paper B's particle filter (:mod:`common.localization.particle_filter`) over the
  body state ``(x, y, z, roll, pitch, yaw)``, initialised around the start guess, its prediction driven by the
  VO velocity and Euler-angle rates. ``pose/pf`` carries the cloud's mean and covariance; its
  ``tracking_state`` is ``tracking`` while the best particle fits (``best_fit >= collapse_fit``),
  ``searching`` during a run of poorly fitting frames, ``lost`` on the frame the filter re-initialised after
  the likelihood collapsed (the pose is then the centre of the fresh, wide cloud). With VO poses in the
  model's frame, an estimate outside the start box around the VO pose reads ``searching``, and after
  :data:`VO_DISAGREE_FRAMES` such frames the cloud starts again around the VO pose (``lost`` on that frame).
- :class:`ModelTrackerPath`: the model tracker (:mod:`common.localization.tracker`), which needs no odometry
  and uses the VO velocity and world-frame angular rate when given, else the gyro's mean rate over the frame
  interval when given (:func:`mean_gyro_camera`); ``tracking_state`` is its own status.

The cores stay state in, state out; these wrappers only hold the current state and the random generator.
"""

from __future__ import annotations

import bisect
import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from common.camera import CameraModel
from common.geometry import (
    euler_from_quaternion,
    matrix_from_quaternion,
    quaternion_from_euler,
    quaternion_from_matrix,
    wrap_angle_rad,
)
from common.localization.particle_filter import (
    ParticleFilter,
    ParticleState,
    PoseStatistics,
    covariance_with_world_error_angles,
)
from common.localization.pose import CameraPose, rotation_vectors
from common.localization.tracker import ModelTracker
from common.localization.tracker_state import TrackerState, TrackingStatus
from common.localization.tracking import localizer_step
from common.wire.messages import Frame, PoseEstimate
from services.localizer.loading import load_scene, localizer_camera
from services.localizer.settings import LocalizerKind, LocalizerSettings

logger = logging.getLogger(__name__)

#: two successive VO poses (previous, current) or None when there are not yet two
VoPair = tuple[PoseEstimate, PoseEstimate] | None


@dataclass(frozen=True)
class StepInputs:
    """What one step takes: the frame, the time since the previous one (s), the last two VO poses, the gyro's
    mean rate over the interval in the camera frame (rad/s), and ``anchor``: a VO pose to start again around
    before this frame (the first VO pose, or the first after a VO discontinuity; see :func:`vo_jumped`)."""

    frame: Frame
    dt_s: float
    vo: VoPair = None
    gyro_camera_rad_s: np.ndarray | None = None
    anchor: PoseEstimate | None = None


class LocalizationPath(Protocol):
    """One frame in, the ``pose/pf`` message out."""

    kind: LocalizerKind
    #: the camera it tracks with (the settings' or an adopted stream rig's)
    camera: CameraModel
    #: whether the last step searched (a long step: the service then catches up through the frames queued
    #: meanwhile)
    searched: bool

    def step(self, inputs: StepInputs) -> PoseEstimate: ...


def body_state_of(pose: PoseEstimate) -> np.ndarray:
    """The body state ``(x, y, z, roll, pitch, yaw)`` (m, rad) of a pose message."""
    return np.concatenate([pose.p_world_body_m, euler_from_quaternion(pose.q_world_body)])


def vo_jumped(previous: PoseEstimate, current: PoseEstimate, max_speed_m_s: float) -> bool:
    """True when the VO moved faster than ``max_speed_m_s`` between two poses (time advancing): the
    odometry restarted, or the stream looped, and its motion across that step is not a motion."""
    odometry = odometry_between(previous, current)
    return odometry is not None and float(np.linalg.norm(odometry[0])) > max_speed_m_s


def vo_over_interval(history: Sequence[PoseEstimate], after_s: float | None, until_s: float) -> VoPair:
    """The two VO poses whose motion stands for the frame interval ``(after_s, until_s]``, from ``history``
    (one VO epoch's poses, time advancing): the latest stamped at or before ``after_s`` and the latest at or
    before ``until_s``. After skipped frames (a stalled host) the filter so predicts with the VO's motion over
    the whole gap, not the last pair's velocity times it (a 3 s stall left the particle filter 0.4-0.5 m off
    the office flight). When the two are one pose (no VO pose inside the interval yet: the VO lags the
    frames) or there is no earlier frame, the last two poses up to ``until_s``; from the epoch's first pose
    when it began inside the interval; the first two when all are later than ``until_s``. None with fewer
    than two poses."""
    if len(history) < 2:
        return None
    stamps = [pose.stamp_s for pose in history]
    end = max(bisect.bisect_right(stamps, until_s) - 1, 1)
    start = end - 1 if after_s is None else max(bisect.bisect_right(stamps, after_s) - 1, 0)
    if start >= end:
        start = end - 1
    return history[start], history[end]


def mean_gyro_camera(
    stamps_s: np.ndarray,
    gyro_body_rad_s: np.ndarray,
    after_s: float,
    until_s: float,
    R_body_camera: np.ndarray,
) -> np.ndarray | None:
    """The mean body rate of the gyro readings stamped in ``(after_s, until_s]``, turned into the camera
    frame (``w_camera = R_body_camera^T w_body``); None when there is none."""
    inside = (stamps_s > after_s) & (stamps_s <= until_s)
    if not np.any(inside):
        return None
    return np.asarray(R_body_camera.T @ gyro_body_rad_s[inside].mean(axis=0), dtype=np.float64)


def odometry_between(previous: PoseEstimate, current: PoseEstimate) -> tuple[np.ndarray, np.ndarray] | None:
    """World velocity (m/s) and world-frame angular rate (rad/s) between two VO poses; None unless time
    advanced."""
    dt = current.stamp_s - previous.stamp_s
    if dt <= 0.0:
        return None
    velocity = (current.p_world_body_m - previous.p_world_body_m) / dt
    turn = matrix_from_quaternion(current.q_world_body) @ matrix_from_quaternion(previous.q_world_body).T
    return velocity, rotation_vectors(turn[None])[0] / dt


def euler_odometry_between(
    previous: PoseEstimate, current: PoseEstimate
) -> tuple[np.ndarray, np.ndarray] | None:
    """World velocity (m/s) and Euler-angle rates (rad/s, wrapped) between two VO poses, as paper B's
    motion model takes them; None unless time advanced."""
    odometry = odometry_between(previous, current)
    if odometry is None:
        return None
    change = euler_from_quaternion(current.q_world_body) - euler_from_quaternion(previous.q_world_body)
    return odometry[0], wrap_angle_rad(change) / (current.stamp_s - previous.stamp_s)


def pose_message(
    uav: str, seq: int, stamp_s: float, state: TrackerState, R_body_camera: np.ndarray
) -> PoseEstimate:
    """The ``pose/pf`` message of a tracker state: the body (``R_world_body = R_world_camera R_body_camera^T``
    with the camera at the body origin), the covariance (camera centre, world-frame error angles), the
    tracking state."""
    R_world_body = state.pose.R_world_camera @ R_body_camera.T
    covariance = np.nan_to_num(state.covariance, nan=0.0)
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=stamp_s,
        p_world_body_m=state.pose.p_world_camera_m.copy(),
        q_world_body=quaternion_from_matrix(R_world_body),
        covariance=0.5 * (covariance + covariance.T),
        source="pf",
        tracking_state=state.status.value,
    )


def particle_tracking_state(state: ParticleState, collapse_fit: float) -> TrackingStatus:
    """``lost`` right after a re-initialisation, ``searching`` while the best fit is below
    ``collapse_fit``, ``tracking`` otherwise (see the module doc)."""
    if state.frames == 0:
        return TrackingStatus.LOST
    if state.low_fit_frames > 0 or state.best_fit < collapse_fit:
        return TrackingStatus.SEARCHING
    return TrackingStatus.TRACKING


def particle_pose_message(
    uav: str, seq: int, stamp_s: float, estimate: PoseStatistics, status: TrackingStatus
) -> PoseEstimate:
    """The ``pose/pf`` message of a particle-cloud estimate: the mean body state, the covariance with
    world-frame error angles."""
    roll, pitch, yaw = estimate.mean[3:]
    covariance = covariance_with_world_error_angles(estimate.mean, estimate.covariance)
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=stamp_s,
        p_world_body_m=estimate.mean[:3].copy(),
        q_world_body=quaternion_from_euler(roll, pitch, yaw),
        covariance=0.5 * (covariance + covariance.T),
        source="pf",
        tracking_state=status.value,
    )


#: frames in a row the particle cloud may sit farther from the VO pose than its start box spreads before it
#: starts again around the VO pose (with VO poses in the model's frame: ``anchor_on_vo``); 0.5 s at 20 fps
VO_DISAGREE_FRAMES = 10


class _ScenePath:
    """What both paths start from: the settings' scene and camera, and a generator seeded with ``seed``."""

    def __init__(self, settings: LocalizerSettings, camera: CameraModel | None = None) -> None:
        self.settings = settings
        self.scene = load_scene(settings)
        self.camera = localizer_camera(settings) if camera is None else camera
        self.rng = np.random.default_rng(settings.seed)


class ParticleFilterPath(_ScenePath):
    """Paper B's particle filter, predicted with the VO odometry (as the service did before the tracker).

    With VO poses in the model's frame (``anchor_on_vo``) they also check the filter: a cloud that settled
    on a wrong pose with a good fit (a window bar, a repeated edge) never collapses, and reported
    ``tracking`` metres away (docker pose/pf: 106 cm). While the estimate lies farther from the VO pose than
    the start box (``init_position_spread_m``), the path reports ``searching``; after
    :data:`VO_DISAGREE_FRAMES` frames it starts the cloud again around the VO pose (``lost`` on that
    frame)."""

    kind = LocalizerKind.PARTICLE
    #: the cloud's steps all cost alike (no search)
    searched = False

    def __init__(self, settings: LocalizerSettings, camera: CameraModel | None = None) -> None:
        super().__init__(settings, camera)
        self.filter = ParticleFilter(self.scene, self.camera, settings.particle_filter_settings())
        guess = settings.start_pose().body_state(settings.R_body_camera)
        self.state: ParticleState = self.filter.initialize(guess, self.rng)
        #: frames in a row the estimate lay outside the start box around the VO pose
        self.vo_disagreement_frames = 0
        #: times the cloud was started again around the VO pose
        self.vo_restarts = 0

    def step(self, inputs: StepInputs) -> PoseEstimate:
        """(The gyro is not used: paper B's motion model takes the VO's Euler-angle rates.) An ``anchor``
        re-initialises the cloud around it (the prior box of the filter's start spreads)."""
        frame, dt_s = inputs.frame, inputs.dt_s
        if inputs.anchor is not None:
            self.state = self.filter.initialize(body_state_of(inputs.anchor), self.rng)
            self.vo_disagreement_frames = 0
            dt_s = 0.0
        odometry = None if inputs.vo is None else euler_odometry_between(*inputs.vo)
        velocity, rates = (None, None) if odometry is None else odometry
        self.state, estimate = localizer_step(
            self.filter, self.state, frame.pixels, dt_s, self.rng, velocity, rates
        )
        if self.settings.anchor_on_vo and inputs.vo is not None:
            estimate = self._check_against_vo(estimate, inputs.vo[1])
        status = particle_tracking_state(self.state, self.filter.config.collapse_fit)
        if self.vo_disagreement_frames and status is TrackingStatus.TRACKING:
            status = TrackingStatus.SEARCHING
        return particle_pose_message(self.settings.uav, frame.seq, frame.stamp_s, estimate, status)

    def _check_against_vo(self, estimate: PoseStatistics, vo: PoseEstimate) -> PoseStatistics:
        """Count the frames the estimate lies outside the start box around the VO pose; after
        :data:`VO_DISAGREE_FRAMES` start the cloud again there (and return the new cloud's estimate)."""
        gap_m = float(np.linalg.norm(estimate.mean[:3] - vo.p_world_body_m))
        if gap_m <= self.filter.config.init_position_spread_m:
            self.vo_disagreement_frames = 0
            return estimate
        self.vo_disagreement_frames += 1
        if self.vo_disagreement_frames < VO_DISAGREE_FRAMES:
            return estimate
        logger.warning(
            "the particle filter sat %.2f m from the VO pose for %d frames: starting again around it",
            gap_m,
            self.vo_disagreement_frames,
        )
        self.vo_restarts += 1
        self.vo_disagreement_frames = 0
        fresh = self.filter.initialize(body_state_of(vo), self.rng)
        self.state = replace(fresh, reinitialisations=self.state.reinitialisations + 1)
        return self.filter.estimate(self.state)


class ModelTrackerPath(_ScenePath):
    """The model tracker (no odometry needed; uses the VO motion when given)."""

    kind = LocalizerKind.TRACKER

    def __init__(self, settings: LocalizerSettings, camera: CameraModel | None = None) -> None:
        super().__init__(settings, camera)
        self.tracker = ModelTracker(self.scene, self.camera, settings.tracker_settings())
        self.state: TrackerState = self.tracker.start(settings.start_pose())
        self.searched = False

    def step(self, inputs: StepInputs) -> PoseEstimate:
        """An ``anchor`` starts the tracker again around it (its start spreads)."""
        frame, dt_s = inputs.frame, inputs.dt_s
        if inputs.anchor is not None:
            pose = CameraPose.from_body_state(body_state_of(inputs.anchor), self.settings.R_body_camera)
            self.state = self.tracker.start(pose)
            dt_s = 0.0
        odometry = None if inputs.vo is None else odometry_between(*inputs.vo)
        velocity, rates = (None, None) if odometry is None else odometry
        self.searched = self.state.search_pending
        self.state = self.tracker.step(
            self.state,
            self.tracker.edges(frame.pixels),
            dt_s,
            self.rng,
            velocity,
            rates,
            gyro_rad_s=inputs.gyro_camera_rad_s if rates is None else None,
        )
        return pose_message(
            self.settings.uav, frame.seq, frame.stamp_s, self.state, self.settings.R_body_camera
        )


def make_path(settings: LocalizerSettings, camera: CameraModel | None = None) -> LocalizationPath:
    """The estimator ``settings.resolved_filter()`` names, with ``camera`` (a stream rig's) or the
    settings'."""
    if settings.resolved_filter() is LocalizerKind.PARTICLE:
        return ParticleFilterPath(settings, camera)
    return ModelTrackerPath(settings, camera)
