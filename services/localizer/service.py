"""The localizer: tracks a known 3D model in a UAV's camera frames with paper B's particle filter (driven by
VO odometry) or the model tracker (no odometry needed: :mod:`common.localization.tracker`); ``--filter``
chooses, ``auto`` takes the particle filter with ``--use-vo`` and the tracker without
(:mod:`services.localizer.filters`).

Subscribes to ``capataz/uav/{uav}/camera`` (and, with ``--use-vo``, to ``.../pose/vo``, whose successive poses
give the prediction its velocity and angular rate; with ``--use-imu``, to ``.../imu``, whose gyro readings
between two frames measure the tracker's angular rate) and publishes ``.../pose/pf``: a
:class:`PoseEstimate` of the body (the camera on its mount) with the 6x6 covariance (position, world-frame
error angles), ``source = "pf"``, ``tracking_state`` (tracking / searching / lost), the frame's ``seq`` and
``stamp_s``. Settings and the command line: :mod:`services.localizer.settings`.

Frames: the subscriber callback only decodes and queues the frame (:class:`~services.runtime.handoff.
FrameQueue`, at most :data:`FRAME_BACKLOG` frames; beyond, the oldest is dropped and counted,
``backlog_overflow``). The filter thread takes the latest frame (the ones it skipped counted,
``dropped_frames``; the step is given the elapsed time since the last frame it used, so a skipped frame only
widens the prediction), except after a search (the first frame's, a recovery's, a start around a VO
anchor) that ended tracking: it then catches up through the frames that arrived meanwhile, in order, until
the queue is empty or a frame is not tracked (the backlog is not a search's input: the next search takes the
latest frame). Bad frames are refused with a log line
and a counter, never a crash: undecodable (``malformed``), a size that is not the camera's (``bad_frames``),
and what the input gate (:class:`~services.runtime.gate.InputGate`) refuses of every input, frames, VO poses
and IMU samples alike (``refused_<sensor>_<reason>``: another UAV's, a second sender's, a seq or stamp that
jumps, goes back or lies in the future).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from typing import Any

import numpy as np
import zenoh

from common.camera import CameraModel
from common.members import Role
from common.streams import GateVerdict
from common.wire import keys
from common.wire.messages import Frame, ImuSample, PoseEstimate, UavMessage
from services.localizer.filters import (
    LocalizationPath,
    StepInputs,
    VoPair,
    make_path,
    mean_gyro_camera,
    odometry_between,
    vo_jumped,
    vo_over_interval,
)
from services.localizer.loading import localizer_camera
from services.localizer.settings import LocalizerSettings, register_arguments, settings_from_args
from services.runtime.gate import InputGate
from services.runtime.handoff import FrameQueue
from services.runtime.rig_follow import follow_stream_rig
from services.runtime.service import ConfiguredService
from services.runtime.trajectory import register_estimating_service
from services.runtime.transport import source_of

logger = logging.getLogger(__name__)

#: gyro readings kept between frames (10 s of a 400 Hz IMU)
IMU_BUFFER = 4000
#: frames kept while a search runs, to catch up through afterwards (5 s at 20 fps, 30 MB at 640x480)
FRAME_BACKLOG = 100
#: VO poses kept for the frame intervals' odometry (25 s at 20 fps: longer than any stall worth bridging)
VO_HISTORY = 512


class LocalizerService(ConfiguredService[LocalizerSettings]):
    role = Role.LOCALIZER

    def setup(self) -> None:
        settings = self.settings
        self.camera = localizer_camera(settings)
        self.path: LocalizationPath = make_path(settings)
        self._frames: FrameQueue[Frame] = FrameQueue(FRAME_BACKLOG)
        self._last_stamp_s: float | None = None  # of the last frame the filter used
        self._last_received_s: float | None = None  # of the last frame accepted by the subscriber
        self._vo_lock = threading.Lock()
        self._vo_previous: PoseEstimate | None = None
        #: the current VO epoch's latest poses, time advancing (each frame interval's odometry)
        self._vo_history: deque[PoseEstimate] = deque(maxlen=VO_HISTORY)
        #: the VO stream's epoch (+1 at its first pose and at each discontinuity) and, with anchor_on_vo,
        #: the epoch the filter last started from (around the latest VO pose)
        self._vo_epoch = -1
        self._used_epoch = -1
        #: gyro readings (stamp, body rate), bounded: seconds of a 400 Hz IMU
        self._imu_lock = threading.Lock()
        self._imu: deque[tuple[float, np.ndarray]] = deque(maxlen=IMU_BUFFER)
        #: the one input gate (UAV, sender, seq, stamps): a future stamp is refused before it can become the
        #: "previous" stamp (one would freeze the filter)
        self.gate = InputGate(settings.uav, self)
        #: the stream's rig (no camera options given): a camera other than the localizer's is adopted, the
        #: filter rebuilt for it on its thread (``_pending_camera``); the mount stays the localizer's
        #: ``--mount`` (it says which body ``pose/pf`` reports)
        self.rigs = follow_stream_rig(settings.uav, self, settings.camera)
        self._rig_lock = threading.Lock()
        self._pending_camera: CameraModel | None = None

    def healthy(self) -> tuple[bool, str]:
        refused = self.gate.recent_refusals()
        if refused:
            return False, f"degraded: {refused} inputs refused in the last {self.gate.window_s:.0f} s"
        return True, "ok"

    def _admit(self, sensor: str, msg: UavMessage, sample: zenoh.Sample) -> bool:
        """Through the input gate (counted there when refused)."""
        return self.gate.admit(sensor, msg, source_of(sample)).verdict is not GateVerdict.REFUSE

    def start(self, session: zenoh.Session) -> None:
        uav = self.settings.uav
        self._publisher = session.declare_publisher(keys.pose_pf_key(uav))
        self.subscriptions.append(session.declare_subscriber(keys.camera_key(uav), self._on_frame))
        if self.rigs is not None:
            self.subscriptions.append(self.rigs.start(session))
        if self.settings.use_vo:
            self.subscriptions.append(session.declare_subscriber(keys.pose_vo_key(uav), self._on_vo))
        if self.settings.use_imu:
            self.subscriptions.append(session.declare_subscriber(keys.imu_key(uav), self._on_imu))
        self.spawn(self._localize, "localize")

    def queue_depths(self) -> dict[str, int]:
        return {"frames": self._frames.depth()}

    # -- callbacks: decode, check, hand off --------------------------------------------------------------
    def _on_frame(self, sample: zenoh.Sample) -> None:
        frame = self.decode_sample(sample, Frame)
        if frame is None or not self._follow_rig(frame):
            return
        if (frame.width, frame.height) != (self.camera.width, self.camera.height):
            self.count_error(
                "bad_frames",
                "frame refused",
                f"size {frame.width}x{frame.height}, the camera is {self.camera.width}x{self.camera.height}",
            )
            return
        decision = self.gate.admit("camera", frame, source_of(sample))
        if decision.verdict is GateVerdict.REFUSE:
            return
        if decision.verdict is GateVerdict.NEW_EPOCH:
            self._last_received_s = None  # a restarted camera: its stamps may begin before the old ones
        if self._last_received_s is not None and frame.stamp_s <= self._last_received_s:
            self.count_error(
                "stale_frames", "frame refused", f"stamp {frame.stamp_s} not after {self._last_received_s}"
            )
            return
        self._last_received_s = frame.stamp_s
        self.counters.inc("frames_in")
        if self._frames.put(frame):
            self.counters.inc("backlog_overflow")

    def _follow_rig(self, frame: Frame) -> bool:
        """False (counted by the follower) for a frame of a rig not received; a rig whose camera is not the
        localizer's is adopted (its filter rebuilt on the filter thread before the next frame)."""
        if self.rigs is None:
            return True
        rig, known = self.rigs.rig_of(frame)
        if rig is None:
            return known
        if rig.camera != self.camera:
            logger.info("%s: the stream's rig %s has another camera: tracking with %s", self.name, rig.rig_id,
                        rig.camera)  # fmt: skip
            with self._rig_lock:
                self.camera = self._pending_camera = rig.camera
            self.counters.inc("rigs_adopted")
        return True

    def _take_pending_camera(self) -> None:
        """Filter thread: a filter for an adopted camera (the frames of another size queued before it are
        dropped, counted)."""
        with self._rig_lock:
            camera, self._pending_camera = self._pending_camera, None
        if camera is not None:
            self.path = make_path(self.settings, camera)
            self._last_stamp_s = None

    def _on_vo(self, sample: zenoh.Sample) -> None:
        pose = self.decode_sample(sample, PoseEstimate)
        if pose is None or not self._admit("vo", pose, sample):
            return
        self._accept_vo(pose)

    def _accept_vo(self, pose: PoseEstimate) -> None:
        """Keep the VO poses (time advancing, bounded) for the prediction; a step faster than
        ``vo_jump_m_s`` begins a new VO epoch instead (see :meth:`_take_anchor`)."""
        with self._vo_lock:
            previous, self._vo_previous = self._vo_previous, pose
            if previous is None:
                self._vo_epoch += 1
                self._vo_history.append(pose)
                return
            if odometry_between(previous, pose) is None:
                self.count_error(
                    "stale_vo", "VO pose refused", f"stamp {pose.stamp_s} not after {previous.stamp_s}"
                )
                return
            if vo_jumped(previous, pose, self.settings.vo_jump_m_s):
                # a restart of the odometry or a loop of the stream: not a motion to predict with
                self._vo_history.clear()
                self._vo_history.append(pose)
                self._vo_epoch += 1
                self.counters.inc("vo_jumps")
                logger.warning(
                    "VO jumped %.2f m in %.3f s (faster than %.1f m/s)%s",
                    float(np.linalg.norm(pose.p_world_body_m - previous.p_world_body_m)),
                    pose.stamp_s - previous.stamp_s,
                    self.settings.vo_jump_m_s,
                    ": starting again around the new VO pose" if self.settings.anchor_on_vo else "",
                )
                return
            self._vo_history.append(pose)

    def vo_between(self, after_s: float | None, until_s: float) -> VoPair:
        """The VO poses whose motion stands for the frame interval (:func:`vo_over_interval`)."""
        with self._vo_lock:
            return vo_over_interval(list(self._vo_history), after_s, until_s)

    def _take_anchor(self) -> PoseEstimate | None:
        """With ``anchor_on_vo``: the latest VO pose, once per VO epoch (the first VO pose, the first after
        a jump), for the filter to start around; None otherwise."""
        with self._vo_lock:
            if not self.settings.anchor_on_vo or self._vo_epoch == self._used_epoch:
                return None
            self._used_epoch = self._vo_epoch
            return self._vo_previous

    def _on_imu(self, sample: zenoh.Sample) -> None:
        reading = self.decode_sample(sample, ImuSample)
        if reading is None or not self._admit("imu", reading, sample):
            return
        if not np.all(np.isfinite(reading.gyro_rad_s)):
            self.count_error("bad_imu", "IMU sample refused", "gyro not finite")
            return
        with self._imu_lock:
            self._imu.append((reading.stamp_s, np.asarray(reading.gyro_rad_s, dtype=np.float64)))
        self.counters.inc("imu_in")

    def _gyro_between(self, after_s: float | None, until_s: float) -> np.ndarray | None:
        """The camera-frame mean gyro rate over the frame interval (readings up to ``until_s`` are used
        once and dropped)."""
        with self._imu_lock:
            readings = [r for r in self._imu if r[0] <= until_s]
            for _ in readings:
                self._imu.popleft()
        if after_s is None or not readings:
            return None
        stamps = np.array([r[0] for r in readings])
        rates = np.array([r[1] for r in readings])
        return mean_gyro_camera(stamps, rates, after_s, until_s, self.settings.R_body_camera)

    # -- the filter thread ------------------------------------------------------------------------------
    def _next_frame(self, catching_up: bool) -> Frame | None:
        """The oldest queued frame while catching up, else the newest (the skipped ones counted)."""
        if catching_up:
            return self._frames.take(0.1)
        frame, skipped = self._frames.take_latest(0.1)
        if skipped:
            self.counters.inc("dropped_frames", skipped)
        return frame

    def _localize(self) -> None:
        catching_up = False
        while not self.stop_event.is_set():
            frame = self._next_frame(catching_up)
            self._take_pending_camera()
            if frame is None:
                catching_up = False
                continue
            if (frame.width, frame.height) != (self.path.camera.width, self.path.camera.height):
                self.counters.inc("dropped_frames")  # queued before the stream's camera changed
                continue
            dt = 0.0 if self._last_stamp_s is None else frame.stamp_s - self._last_stamp_s
            gyro = self._gyro_between(self._last_stamp_s, frame.stamp_s) if self.settings.use_imu else None
            vo = self.vo_between(self._last_stamp_s, frame.stamp_s)
            self._last_stamp_s = frame.stamp_s
            anchor = self._take_anchor()
            if anchor is not None:
                self.counters.inc("vo_anchors")
                logger.info("starting around the VO pose of %.3f s", anchor.stamp_s)
            t0 = time.perf_counter()
            message = self.path.step(StepInputs(frame, dt, vo, gyro, anchor))
            self.counters.time_ms("step", (time.perf_counter() - t0) * 1e3)
            behind = catching_up
            catching_up = (
                (catching_up or self.path.searched)
                and message.tracking_state == "tracking"
                and self._frames.depth() > 0
            )
            if catching_up and not behind:
                self.counters.inc("catch_ups")  # frames queued behind a search, now taken in order
            self.counters.inc(f"frames_{message.tracking_state}")
            if not self.publish(self._publisher, message):
                return  # shutting down: the session is closing under us
            if self.trajectory_tap is not None:
                self.trajectory_tap.write(message)
            self.counters.inc("poses_out")


def register(subparsers: Any) -> None:
    register_estimating_service(
        subparsers,
        "localizer",
        "tracks a known 3D model (JSON, OBJ, ViSP .cao) in the camera frames with paper B's particle "
        "filter (--use-vo odometry) or the model tracker (--filter); publishes pose/pf",
        register_arguments,
        lambda args: LocalizerService.from_args(args, settings_from_args(args)),
        {PoseEstimate: ("--trajectory", "pose/pf")},
    )
