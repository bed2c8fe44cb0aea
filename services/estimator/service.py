"""The estimator: paper C's EKF with visual odometry and double coupling, for one UAV's streams.

Subscribes to ``capataz/uav/{uav}/imu``, ``.../range``, ``.../camera`` (and, with ``--external-yaw``, to
``.../yaw`` of the yaw cluster) and publishes

- ``capataz/uav/{uav}/attitude``: an :class:`AttitudeEstimate` after every IMU sample (the EKF's attitude,
  3x3 world-frame error-angle covariance);
- ``capataz/uav/{uav}/pose/vo``: a :class:`PoseEstimate` after every frame (x, y from the visual odometry,
  z and attitude from the EKF), ``source = "vo"``.

Callbacks only decode, check and hand off, on zenoh's receiving thread in arrival order, to the
:class:`~services.estimator.backlog.Backlog`: IMU, range and yaw samples to a bounded FIFO (refusals counted
as ``queue_full``), frames to a short :class:`~services.estimator.backlog.SpacedFrameQueue`. A sample's time
is checked once, there (the input gate, :class:`~services.runtime.gate.InputGate`), and so are its
values (:func:`~services.estimator.inputs.measurement_of`); the backlog and the filter's buffer only order
what passed. One thread feeds them to
:class:`~common.estimation.coupling.DoubleCouplingEstimator` in stamp order, one frame at a time, each after
the samples before it. When the filter is behind, every IMU and range sample is still applied and the
frame queue skips frames evenly (``frames_skipped``; ``vo_spacing_<n>`` counts the pairs ``n`` frames
apart), so the VO pairs the frames it gets; health reports degraded while frames are skipped or the
filter lags (``lag_ms`` in the stats). A pose whose pair failed is published as ``lost`` with the unseen
motion in its covariance. Bad samples are refused with a log line and a counter, never a crash:
undecodable (``malformed``), refused by the gate (``refused_<sensor>_<reason>``: another UAV's, a second
sender's, a frame's seq jump, a stamp in the future, jumping or going back), NaN/inf or a wrong shape
(``bad_samples``, ``bad_frames``), stale or duplicate stamps in the filter
(``refused_<sensor>_<stale|duplicate|overflow>``).
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from collections import deque
from typing import Any, TypeVar

import zenoh

from common.errors import InputError
from common.estimation.buffer import Refusal
from common.estimation.measurements import FrameMeasurement, Measurement
from common.members import Role
from common.rig import Rig
from common.streams import GateVerdict
from common.wire import keys
from common.wire.messages import (
    AttitudeEstimate,
    Frame,
    ImuSample,
    PoseEstimate,
    RangeSample,
    UavMessage,
    YawEstimate,
)
from services.estimator.backlog import Backlog
from services.estimator.inputs import WHAT, Input, measurement_of
from services.estimator.outputs import Publication, VoPath
from services.estimator.settings import (
    EstimatorSettings,
    add_estimator_arguments,
    build_estimator,
    configured_rig,
    settings_from_args,
)
from services.runtime.cli import add_transport_arguments
from services.runtime.gate import InputGate
from services.runtime.rig_follow import follow_stream_rig
from services.runtime.service import ConfiguredService
from services.runtime.trajectory import register_estimating_service
from services.runtime.transport import source_of

S = TypeVar("S", bound=UavMessage)
logger = logging.getLogger(__name__)
SENSOR_QUEUE = 4096
#: samples the filter refuses as stale in a row before it is rebuilt (the stream's clock went back: a restart)
RESET_AFTER_STALE = 400
#: seconds without an output, while inputs arrive, after which health reports degraded
OUTPUT_SILENCE_S = 2.0
#: seconds over which skipped frames keep health degraded, and the lag behind the inputs that degrades it
BEHIND_WINDOW_S = 5.0
BEHIND_LAG_MS = 1000
#: pair spacings (frames) counted one by one; wider ones as ``vo_spacing_<n>_plus``
SPACING_BINS = 6


class EstimatorService(ConfiguredService[EstimatorSettings]):
    role = Role.ESTIMATOR

    def setup(self) -> None:
        settings = self.settings
        self.estimator = build_estimator(settings)
        logger.info("%s: %s", self.name, settings.rig_mount.describe())
        self._shape = self.estimator.camera.shape
        #: the stream's rig (None: camera or mount options given, they override it); a new one is adopted by
        #: the estimator thread at its next turn (the filter rebuilt with its camera and mount)
        self.rigs = follow_stream_rig(settings.uav, self, settings.camera, settings.rig_mount)
        self._rig_id = configured_rig(settings).rig_id  # a stream rig equal to it changes nothing
        self._pending_rig: Rig | None = None
        #: the samples and frames handed off by the callbacks; frames wait in a short queue (a busy moment
        #: costs latency, not frames: VO pairs stay one apart), a longer backlog skips frames evenly, and the
        #: VO pairs the frames it gets; samples newer than a queued frame are held until it is pushed
        self._backlog: Backlog[Measurement, FrameMeasurement] = Backlog(
            SENSOR_QUEUE, settings.frame_queue, settings.max_pair_s, settings.max_backlog_s
        )
        #: (monotonic time, spacing) of the recent frames taken after skipped ones
        self._skips: deque[tuple[float, int]] = deque(maxlen=1024)
        self._newest_in_s = -math.inf
        self._mirrored: dict[str, int] = {}
        self._publication = Publication(settings.uav, settings.max_pair_s, settings.published_uncertainty())
        #: the one input gate: UAV, sender, seq (frames), stamps of every input, before anything else
        self.gate = InputGate(settings.uav, self)
        self._stale_run = 0
        self._last_input_s = 0.0
        self._last_output_s = time.monotonic()

    def start(self, session: zenoh.Session) -> None:
        uav = self.settings.uav
        self._attitude_pub = session.declare_publisher(keys.attitude_key(uav))
        self._pose_pub = session.declare_publisher(keys.pose_vo_key(uav))
        # indirect=False: the callbacks run on zenoh's receiving thread, in the order the samples arrived.
        # With zenoh's default (a Python thread per subscriber) a frame decoded on its own thread could reach
        # the time-ordered buffer after IMU samples more than the lag newer, and be refused as stale, when
        # the machine is loaded (seen in the service test under CPU load: a pose missing).
        wanted = [(keys.imu_key(uav), self._on_imu), (keys.range_key(uav), self._on_range)]
        wanted.append((keys.camera_key(uav), self._on_frame))
        if self.settings.external_yaw:
            wanted.append((keys.yaw_key(uav), self._on_yaw))
        for key, on_sample in wanted:
            handler = zenoh.handlers.Callback(on_sample, indirect=False)
            self.subscriptions.append(session.declare_subscriber(key, handler))
        if self.rigs is not None:
            self.subscriptions.append(self.rigs.start(session))
        self.spawn(self._estimate, "estimate")

    def healthy(self) -> tuple[bool, str]:
        refused = self.gate.recent_refusals()
        if refused:
            return False, f"degraded: {refused} inputs refused in the last {self.gate.window_s:.0f} s"
        cutoff = time.monotonic() - BEHIND_WINDOW_S
        recent = [spacing for t, spacing in list(self._skips) if t >= cutoff]
        if recent:
            c = self.counters
            return False, (
                f"degraded: behind, {sum(recent) - len(recent)} frames skipped in the last "
                f"{BEHIND_WINDOW_S:.0f} s (VO pairs up to {max(recent)} frames apart; "
                f"{c.get('frames_used')} of {c.get('frames_in')} frames used)"
            )
        if (lag_ms := self.lag_ms()) > BEHIND_LAG_MS:
            return False, f"degraded: behind, the filter is {lag_ms / 1e3:.1f} s behind the newest input"
        now = time.monotonic()
        if now - self._last_input_s < 1.0 and now - self._last_output_s > OUTPUT_SILENCE_S:
            return False, f"degraded: inputs arrive but no output for {now - self._last_output_s:.1f} s"
        return True, "ok"

    def queue_depths(self) -> dict[str, int]:
        return {**self._backlog.depths(), "buffer": len(self.estimator.buffer), "lag_ms": self.lag_ms()}

    def lag_ms(self) -> int:
        """How far the filter is behind the newest input (stamps, ms)."""
        released_s = self.estimator.buffer.released_until_s
        if not (math.isfinite(released_s) and math.isfinite(self._newest_in_s)):
            return 0
        return max(0, round(1e3 * (self._newest_in_s - released_s)))

    # -- callbacks: decode, check, hand off ----------------------------------------------------------
    def _on_imu(self, sample: zenoh.Sample) -> None:
        self._receive(sample, ImuSample, "imu")

    def _on_range(self, sample: zenoh.Sample) -> None:
        self._receive(sample, RangeSample, "range")

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        self._receive(sample, YawEstimate, "yaw")

    def _on_frame(self, sample: zenoh.Sample) -> None:
        self._receive(sample, Frame, "camera")

    def _receive(self, sample: zenoh.Sample, expected: type[Input], sensor: str) -> None:
        """Decoded, then through the input gate (another UAV's, a second sender's, a frame whose seq jumps,
        a stamp in the future or jumping: refused, counted); its values checked; then handed off."""
        msg = self.decode_sample(sample, expected)
        if msg is None:
            return
        what = WHAT[sensor]
        self._last_input_s = time.monotonic()
        decision = self.gate.admit(sensor, msg, source_of(sample))
        if decision.verdict is GateVerdict.REFUSE:
            return
        if decision.verdict is GateVerdict.NEW_EPOCH:
            self._newest_in_s = msg.stamp_s
        else:
            self._newest_in_s = max(self._newest_in_s, msg.stamp_s)
        if isinstance(msg, Frame) and self.rigs is not None:
            rig, known = self.rigs.rig_of(msg)
            if not known:  # a rig not received: counted, asked for
                return
            if rig is not None and rig.rig_id != self._rig_id:
                self._rig_id, self._pending_rig = rig.rig_id, rig
                self._shape = rig.camera.shape
        if isinstance(msg, YawEstimate) and msg.low_confidence:
            self.counters.inc("yaw_low_confidence")
            return
        try:
            measurement = measurement_of(msg, self._shape)
        except InputError as exc:
            frame = sensor == "camera"
            self.count_error("bad_frames" if frame else "bad_samples", f"{what} refused", exc)
            return
        if isinstance(measurement, FrameMeasurement):
            self.counters.inc("frames_in")
            if self._backlog.offer_frame(measurement) is not None:
                self.count_error(
                    "frames_skipped", "frame skipped", "the filter is behind: VO pairs spaced out"
                )
        elif not self._backlog.samples.offer(measurement):
            self.count_error("queue_full", "sample refused", "the sensor queue is full")

    # -- the estimator thread ------------------------------------------------------------------------
    def _refused(self, measurement: Measurement, refusal: Refusal) -> None:
        """A sample the filter refused: counted; a long run of stale ones rebuilds the filter."""
        name = type(measurement).__name__.removesuffix("Measurement").lower()
        self.count_error(
            f"refused_{name}_{refusal.value}",
            "sample refused",
            f"{refusal.value} stamp {measurement.stamp_s}",
        )
        self.gate.note_refusal()
        self._stale_run = self._stale_run + 1 if refusal is Refusal.STALE else 0
        if self._stale_run >= RESET_AFTER_STALE:
            # the stream's clock went back for good (a restarted sensor stack): start a new filter
            self.count_error(
                "estimator_resets", "filter rebuilt", f"{self._stale_run} stale samples in a row"
            )
            self.estimator = build_estimator(self.settings)
            self._stale_run = 0
            self._publication.path = VoPath()

    def _estimate(self) -> None:
        while not self.stop_event.is_set():
            self.step(0.02)

    def step(self, timeout_s: float) -> bool:
        """One turn of the estimator thread (:meth:`Backlog.next <services.estimator.backlog.Backlog.next>`):
        the samples pushed to the filter and applied, then the frame, if one was queued, pushed and applied
        (the filter is brought up to a frame before it is pushed: a frame pushed while an older one is still
        pending would supersede it; every IMU and range sample is applied, frames or not); the outputs
        published and the counters updated once. Waits up to ``timeout_s`` for a sample when nothing is
        queued; True when a frame was taken."""
        if (rig := self._pending_rig) is not None:  # the stream's rig, new or changed: a filter for it
            self._pending_rig = None
            self.estimator = build_estimator(self.settings, rig)
            self._publication.path = VoPath()
            self.counters.inc("rigs_adopted")
        turn = self._backlog.next(timeout_s)
        for m in turn.samples:
            if (refusal := self.estimator.push(m)) is None:
                self._stale_run = 0
            else:
                self._refused(m, refusal)
        t0 = time.perf_counter()
        outputs = self.estimator.process_due()
        counts: dict[str, int] = {}
        if turn.frame is not None:
            if (refusal := self.estimator.push(turn.frame)) is None:
                self._stale_run = 0
                counts["frames_used"] = 1
                if turn.spacing > 1:
                    self._skips.append((time.monotonic(), turn.spacing))
                wide = turn.spacing >= SPACING_BINS
                counts[f"vo_spacing_{SPACING_BINS}_plus" if wide else f"vo_spacing_{turn.spacing}"] = 1
            else:
                self._refused(turn.frame, refusal)
            outputs += self.estimator.process_due()
        process_ms = (time.perf_counter() - t0) * 1e3
        if outputs:
            self._last_output_s = time.monotonic()
        published = self._publication.publish(
            outputs, self.publish, self._attitude_pub, self._pose_pub, self.trajectory_tap
        )
        counts.update(published)
        # the filter's own counters, mirrored (its refusals are counted where they were pushed)
        for name, value in self.estimator.counters.items():
            delta = value - self._mirrored.get(name, 0)
            if delta and not name.startswith("refused_"):
                counts[name] = counts.get(name, 0) + delta
                self._mirrored[name] = value
        self.counters.update(counts, {"process": process_ms})
        return turn.frame is not None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_transport_arguments(parser, node_default="estimator")
    add_estimator_arguments(parser)


def register(subparsers: Any) -> None:
    register_estimating_service(
        subparsers,
        "estimator",
        "EKF + visual odometry with double coupling (paper C); publishes attitude, pose/vo",
        add_arguments,
        lambda args: EstimatorService.from_args(args, settings_from_args(args)),
        {
            PoseEstimate: ("--trajectory", "pose/vo"),
            AttitudeEstimate: ("--attitude-trajectory", "the attitude (position 0)"),
        },
    )
