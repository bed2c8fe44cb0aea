"""The estimator: paper C's EKF with visual odometry and double coupling, for one UAV's streams.

Subscribes to ``capataz/uav/{uav}/imu``, ``.../range``, ``.../camera`` (and, with ``--external-yaw``, to
``.../yaw`` of the yaw cluster) and publishes

- ``capataz/uav/{uav}/attitude``: an :class:`AttitudeEstimate` after every IMU sample (the EKF's attitude,
  3x3 world-frame error-angle covariance);
- ``capataz/uav/{uav}/pose/vo``: a :class:`PoseEstimate` after every frame (x, y from the visual odometry,
  z and attitude from the EKF), ``source = "vo"``.

Callbacks only decode, validate and hand off, on zenoh's receiving thread in arrival order: IMU, range and
yaw samples to a bounded FIFO (refusals counted as ``queue_full``), frames to a short
:class:`~services.estimator.backlog.SpacedFrameQueue`. One thread feeds them to
:class:`~common.estimation.coupling.DoubleCouplingEstimator` in stamp order, one frame at a time, each after
the samples before it. When the filter is behind, every IMU and range sample is still applied and the
frame queue skips frames evenly (``frames_skipped``; ``vo_spacing_<n>`` counts the pairs ``n`` frames
apart), so the VO pairs the frames it gets; health reports degraded while frames are skipped or the
filter lags (``lag_ms`` in the stats). A pose whose pair failed is published as ``lost`` with the unseen
motion in its covariance. Bad samples are refused with a log line and a counter, never a crash:
undecodable (``malformed``), another UAV's (``wrong_uav``), NaN/inf or a wrong shape (``bad_samples``,
``bad_frames``), stale or duplicate stamps (``refused_<sensor>_<stale|duplicate|overflow>``).
"""

from __future__ import annotations

import argparse
import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import zenoh

from common.errors import InputError
from common.estimation.buffer import Refusal
from common.estimation.coupling_types import AttitudeOutput, PoseOutput
from common.estimation.measurements import (
    FrameMeasurement,
    Measurement,
    check_frame,
    check_imu,
    check_range,
    check_yaw,
)
from common.members import Role
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
from common.wire.schema import WireModel
from services.estimator.backlog import HeldSamples, SpacedFrameQueue
from services.estimator.outputs import (
    VoPath,
    advance_path,
    attitude_message,
    horizontal_variance,
    pose_message,
)
from services.estimator.settings import (
    EstimatorSettings,
    add_estimator_arguments,
    build_estimator,
    settings_from_args,
)
from services.runtime.cli import add_transport_arguments
from services.runtime.handoff import WorkQueue
from services.runtime.service import ConfiguredService
from services.runtime.stamps import InputStamps
from services.runtime.trajectory import add_trajectory_argument, run_with_trajectories

S = TypeVar("S", bound=UavMessage)
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
        self._shape = self.estimator.camera.shape
        self._samples: WorkQueue[Measurement] = WorkQueue(SENSOR_QUEUE)
        #: frames wait in a short queue (a busy moment costs latency, not frames: VO pairs stay one apart);
        #: a longer backlog skips frames evenly, and the VO pairs the frames it gets
        self._frames: SpacedFrameQueue[FrameMeasurement] = SpacedFrameQueue(
            settings.frame_queue, settings.max_pair_s, settings.max_backlog_s
        )
        #: samples drained but held back until the frames queued before them are pushed (stamp order)
        self._held: HeldSamples[Measurement] = HeldSamples(SENSOR_QUEUE)
        #: (monotonic time, spacing) of the recent frames taken after skipped ones
        self._skips: deque[tuple[float, int]] = deque(maxlen=1024)
        self._newest_in_s = -math.inf
        self._mirrored: dict[str, int] = {}
        self._attitude_seq = 0
        self._pose_seq = 0
        self._path = VoPath()
        self.stamps = InputStamps()
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
        self.spawn(self._estimate, "estimate")

    def healthy(self) -> tuple[bool, str]:
        refused = self.stamps.recent_refusals()
        if refused:
            return False, f"degraded: {refused} inputs refused in the last {self.stamps.window_s:.0f} s"
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
        return {
            "samples": self._samples.depth(),
            "frames": self._frames.depth(),
            "held": len(self._held),
            "buffer": len(self.estimator.buffer),
            "lag_ms": self.lag_ms(),
        }

    def lag_ms(self) -> int:
        """How far the filter is behind the newest input (stamps, ms)."""
        released_s = self.estimator.buffer.released_until_s
        if not (math.isfinite(released_s) and math.isfinite(self._newest_in_s)):
            return 0
        return max(0, round(1e3 * (self._newest_in_s - released_s)))

    # -- callbacks: decode, check, hand off ----------------------------------------------------------
    def _own(self, uav: str, what: str, key: Any) -> bool:
        if uav != self.settings.uav:
            self.count_error("wrong_uav", f"{what} of another UAV refused", f"{uav!r} on {key}")
            self.stamps.note_refusal()
            return False
        return True

    def _admit(self, sensor: str, stamp_s: float) -> bool:
        """The stamp guard: a stamp too far ahead of the sensor's recent ones or the wall clock is refused."""
        self._last_input_s = time.monotonic()
        admitted, reason, detail = self.stamps.check(sensor, stamp_s)
        if not admitted:
            self.count_error(f"refused_{sensor}_{reason}", f"{sensor} sample refused", detail)
        elif reason:
            self.count_error("clock_jumps", f"{sensor} clock jump adopted", f"stamp {stamp_s}")
            self._newest_in_s = stamp_s
        else:
            self._newest_in_s = max(self._newest_in_s, stamp_s)
        return admitted

    def _offer(self, measurement: Measurement) -> None:
        if not self._samples.offer(measurement):
            self.count_error("queue_full", "sample refused", "the sensor queue is full")

    def _admitted(self, sample: zenoh.Sample, expected: type[S], what: str, sensor: str) -> S | None:
        """The sample decoded, of this UAV, and with a stamp the guard admits; else None (counted)."""
        msg = self.decode_sample(sample, expected)
        if (
            msg is None
            or not self._own(msg.uav, what, sample.key_expr)
            or not self._admit(sensor, msg.stamp_s)
        ):
            return None
        return msg

    def _offer_checked(self, what: str, check: Callable[[], Measurement]) -> None:
        try:
            self._offer(check())
        except InputError as exc:
            self.count_error("bad_samples", f"{what} refused", exc)

    def _on_imu(self, sample: zenoh.Sample) -> None:
        msg = self._admitted(sample, ImuSample, "IMU sample", "imu")
        if msg is not None:
            self._offer_checked("IMU sample", lambda: check_imu(msg.stamp_s, msg.gyro_rad_s, msg.accel_m_s2))

    def _on_range(self, sample: zenoh.Sample) -> None:
        msg = self._admitted(sample, RangeSample, "range sample", "range")
        if msg is not None:
            self._offer_checked("range sample", lambda: check_range(msg.stamp_s, msg.range_m))

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        msg = self._admitted(sample, YawEstimate, "yaw", "yaw")
        if msg is None:
            return
        if msg.low_confidence:
            self.counters.inc("yaw_low_confidence")
            return
        self._offer_checked("yaw", lambda: check_yaw(msg.stamp_s, msg.yaw_rad))

    def _on_frame(self, sample: zenoh.Sample) -> None:
        msg = self._admitted(sample, Frame, "frame", "camera")
        if msg is None:
            return
        try:
            frame = check_frame(msg.stamp_s, msg.pixels, self._shape)
        except InputError as exc:
            self.count_error("bad_frames", "frame refused", exc)
            return
        self.counters.inc("frames_in")
        skipped = self._frames.offer(frame)
        if skipped is not None:
            self.count_error("frames_skipped", "frame skipped", "the filter is behind: VO pairs spaced out")

    # -- the estimator thread ------------------------------------------------------------------------
    def _push(self, measurement: Measurement) -> bool:
        """Push one sample to the filter; False (counted) when it refused it."""
        refusal = self.estimator.push(measurement)
        if refusal is None:
            self._stale_run = 0
            return True
        name = type(measurement).__name__.removesuffix("Measurement").lower()
        self.count_error(
            f"refused_{name}_{refusal.value}",
            "sample refused",
            f"{refusal.value} stamp {measurement.stamp_s}",
        )
        self.stamps.note_refusal()
        self._stale_run = self._stale_run + 1 if refusal is Refusal.STALE else 0
        if self._stale_run >= RESET_AFTER_STALE:
            # the stream's clock went back for good (a restarted sensor stack): start a new filter
            self.count_error(
                "estimator_resets", "filter rebuilt", f"{self._stale_run} stale samples in a row"
            )
            self.estimator = build_estimator(self.settings)
            self._stale_run = 0
            self._path = VoPath()
        return False

    def _estimate(self) -> None:
        while not self.stop_event.is_set():
            self.step(0.02)

    def step(self, timeout_s: float) -> bool:
        """One turn of the estimator thread: the queued samples, then the oldest queued frame with the
        samples before it (waits up to ``timeout_s`` for a sample when nothing is queued); True when a
        frame was taken."""
        if not self._held and self._frames.depth() == 0:
            first = self._samples.take(timeout_s)
            if first is not None:
                self._push_all(self._held.add([first]))
        # the samples before the frame: a frame still queued after the drain arrived before the samples
        # newer than it (they are held until it is pushed), one arriving later is newer than them all
        self._push_all(self._held.add(self._samples.drain()))
        taken = self._frames.take()
        if taken is None:
            self._push_all(self._held.until(math.inf))
            self._process()
            self._mirror_counters()
            return False
        frame, spacing = taken
        # the filter brought up to the frame before it is pushed (a frame pushed while an older one is
        # still pending would supersede it); every IMU and range sample is applied, frames or not
        self._push_all(self._held.until(frame.stamp_s))
        self._process()
        if self._push(frame):
            self._count_frame(spacing)
        self._process()
        self._mirror_counters()
        return True

    def _push_all(self, samples: list[Measurement]) -> None:
        for m in samples:
            self._push(m)

    def _count_frame(self, spacing: int) -> None:
        self.counters.inc("frames_used")
        if spacing > 1:
            self._skips.append((time.monotonic(), spacing))
        wide = spacing >= SPACING_BINS
        self.counters.inc(f"vo_spacing_{SPACING_BINS}_plus" if wide else f"vo_spacing_{spacing}")

    def _process(self) -> None:
        t0 = time.perf_counter()
        outputs = self.estimator.process_due()
        self.counters.time_ms("process", (time.perf_counter() - t0) * 1e3)
        self._publish(outputs)

    def _publish(self, outputs: list[AttitudeOutput | PoseOutput]) -> None:
        if outputs:
            self._last_output_s = time.monotonic()
        for out in outputs:
            if isinstance(out, AttitudeOutput):
                # each output with its own uncertainty, not the batch's last state's (issue 9 section 5)
                msg: AttitudeEstimate | PoseEstimate = attitude_message(
                    self.settings.uav, self._attitude_seq, out
                )
                self._attitude_seq += 1
                publisher = self._attitude_pub
            else:
                self._path = advance_path(self._path, out, self.settings.max_pair_s)
                var_xy = horizontal_variance(self._path, self.settings.vo_drift_fraction)
                msg = pose_message(self.settings.uav, self._pose_seq, out, var_xy)
                self._pose_seq += 1
                publisher = self._pose_pub
            if not self.publish(publisher, msg):
                return  # shutting down: the session is closing under us
            if self.trajectory_tap is not None:
                self.trajectory_tap.write(msg)
            self.counters.inc("attitudes_out" if isinstance(out, AttitudeOutput) else "poses_out")

    def _mirror_counters(self) -> None:
        for name, value in self.estimator.counters.items():
            if name.startswith("refused_"):
                continue  # counted at the push
            delta = value - self._mirrored.get(name, 0)
            if delta:
                self.counters.inc(name, delta)
                self._mirrored[name] = value


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "estimator", help="EKF + visual odometry with double coupling (paper C); publishes attitude, pose/vo"
    )
    add_transport_arguments(parser, node_default="estimator")
    add_estimator_arguments(parser)
    add_trajectory_argument(parser, "pose/vo")
    add_trajectory_argument(parser, "the attitude (position 0)", flag="--attitude-trajectory")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    service = EstimatorService.from_args(args, settings_from_args(args))
    paths: dict[type[WireModel], Path | None] = {
        PoseEstimate: args.trajectory,
        AttitudeEstimate: args.attitude_trajectory,
    }
    return run_with_trajectories(service, paths)
