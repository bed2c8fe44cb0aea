"""The estimator: paper C's EKF with visual odometry and double coupling, for one UAV's streams.

Subscribes to ``capataz/uav/{uav}/imu``, ``.../range``, ``.../camera`` (and, with ``--external-yaw``, to
``.../yaw`` of the yaw cluster) and publishes

- ``capataz/uav/{uav}/attitude``: an :class:`AttitudeEstimate` after every IMU sample (the EKF's attitude,
  3x3 world-frame error-angle covariance);
- ``capataz/uav/{uav}/pose/vo``: a :class:`PoseEstimate` after every frame (x, y from the visual odometry,
  z and attitude from the EKF), ``source = "vo"``.

Callbacks only decode, validate and hand off, on zenoh's receiving thread in arrival order: IMU, range and
yaw samples to a bounded FIFO (refusals counted as ``queue_full``), frames to a short FIFO (dropped only when
it is full, ``dropped_frames``). One thread feeds them to
:class:`~common.estimation.coupling.DoubleCouplingEstimator`, which applies them in stamp order within a
bounded lag. Bad samples are refused with a log line and a counter, never a crash:
undecodable (``malformed``), another UAV's (``wrong_uav``), NaN/inf or a wrong shape (``bad_samples``,
``bad_frames``), stale or duplicate stamps (``refused_<sensor>_<stale|duplicate|overflow>``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import zenoh

from common import keys
from common.codec import encode
from common.errors import InputError
from common.estimation.buffer import Refusal
from common.estimation.coupling_types import AttitudeOutput, FilterKind, PoseOutput
from common.estimation.measurements import Measurement, check_frame, check_imu, check_range, check_yaw
from common.messages import (
    AttitudeEstimate,
    Frame,
    ImuSample,
    PoseEstimate,
    RangeSample,
    UavMessage,
    YawEstimate,
)
from common.wire import WireModel
from services.estimator.outputs import attitude_message, pose_message
from services.estimator.settings import EstimatorSettings, build_estimator, settings_from_args
from services.runtime.cli import add_enum_argument, add_transport_arguments
from services.runtime.handoff import WorkQueue
from services.runtime.service import ConfiguredService
from services.runtime.stamps import InputStamps
from services.trajectory import add_trajectory_argument, run_with_trajectories

T = TypeVar("T")
S = TypeVar("S", bound=UavMessage)
SENSOR_QUEUE = 4096
FRAME_QUEUE = 40
#: samples the filter refuses as stale in a row before it is rebuilt (the stream's clock went back: a restart)
RESET_AFTER_STALE = 400
#: seconds without an output, while inputs arrive, after which health reports degraded
OUTPUT_SILENCE_S = 2.0


#: queued frames up to which every frame is used (a short stall of the host is worked off, not thinned)
THIN_AFTER = 6


def thin_frames(frames: list[T]) -> list[T]:
    """The frames to use when ``frames`` queued up (the filter is behind): every one while no more than
    :data:`THIN_AFTER` wait, else every second (up to twice that) or third, always the newest. Evenly thinned
    frames keep VO pairs two or three frames apart, which the VO handles; dropping a burst (a full queue)
    left pairs a second apart, which it did not (a busy host ended paper C's flight 0.4-1.9 m off)."""
    n = len(frames)
    if n <= THIN_AFTER:
        return frames
    stride = 2 if n <= 2 * THIN_AFTER else 3
    return frames[n - 1 :: -stride][::-1]


class EstimatorService(ConfiguredService[EstimatorSettings]):
    role = keys.Role.ESTIMATOR

    def setup(self) -> None:
        settings = self.settings
        self.estimator = build_estimator(settings)
        self._shape = self.estimator.camera.shape
        self._samples: WorkQueue[Measurement] = WorkQueue(SENSOR_QUEUE)
        #: frames wait in a short FIFO (a busy moment costs latency, not frames: VO pairs stay one apart);
        #: only when it is full are frames dropped (counted), and the VO pairs the frames it gets
        self._frames: WorkQueue[Measurement] = WorkQueue(FRAME_QUEUE)
        self._entities: list[Any] = []
        self._mirrored: dict[str, int] = {}
        self._attitude_seq = 0
        self._pose_seq = 0
        self._travelled_m = 0.0
        self._last_xy: np.ndarray | None = None
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
            self._entities.append(session.declare_subscriber(key, handler))
        self.spawn(self._estimate, "estimate")

    def stop(self) -> None:
        # subscribers only: the estimate thread may still publish until it is joined (the session closes the
        # publishers; undeclaring them here raced with it: "ZError: Undeclared publisher", exit 1)
        self.undeclare_all(self._entities)

    def healthy(self) -> tuple[bool, str]:
        refused = self.stamps.recent_refusals()
        if refused:
            return False, f"degraded: {refused} inputs refused in the last {self.stamps.window_s:.0f} s"
        now = time.monotonic()
        if now - self._last_input_s < 1.0 and now - self._last_output_s > OUTPUT_SILENCE_S:
            return False, f"degraded: inputs arrive but no output for {now - self._last_output_s:.1f} s"
        return True, "ok"

    def queue_depths(self) -> dict[str, int]:
        return {
            "samples": self._samples.depth(),
            "frames": self._frames.depth(),
            "buffer": len(self.estimator.buffer),
        }

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
        if not self._frames.offer(frame):
            self.count_error(
                "dropped_frames", "frame dropped", "the frame queue is full (the filter is behind)"
            )

    # -- the estimator thread ------------------------------------------------------------------------
    def _push(self, measurement: Measurement) -> None:
        refusal = self.estimator.push(measurement)
        if refusal is None:
            self._stale_run = 0
            return
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
            self._last_xy, self._travelled_m = None, 0.0

    def _estimate(self) -> None:
        while not self.stop_event.is_set():
            first = self._samples.take(0.02)
            # the frame before the drain: every sample published before it is then in this batch, so a queue
            # that is behind never has the frame release the filter past samples still waiting (range samples
            # were refused as stale so under load)
            queued = self._frames.drain()
            frames = thin_frames(queued)
            if len(frames) < len(queued):
                self.counters.inc("frames_thinned", len(queued) - len(frames))
            batch = [] if first is None else [first, *self._samples.drain()]
            if not batch and not frames:
                continue
            # in stamp order, the filter brought up to each frame before it is pushed: a frame pushed while an
            # older one is still pending would supersede it
            batch.sort(key=lambda m: m.stamp_s)
            i = 0
            for frame in frames:
                if self.stop_event.is_set():
                    return  # a long backlog is not worked off at shutdown (the session is closing)
                while i < len(batch) and batch[i].stamp_s <= frame.stamp_s:
                    self._push(batch[i])
                    i += 1
                self._process()
                self._push(frame)
            for m in batch[i:]:
                self._push(m)
            self._process()
            self._mirror_counters()

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
                xy = out.p_world_body_m[:2]
                if self._last_xy is not None:
                    self._travelled_m += float(np.linalg.norm(xy - self._last_xy))
                self._last_xy = xy
                var_xy = (self.settings.vo_drift_fraction * self._travelled_m) ** 2 + 1e-6
                msg = pose_message(self.settings.uav, self._pose_seq, out, var_xy)
                self._pose_seq += 1
                publisher = self._pose_pub
            payload, attachment = encode(msg)
            try:
                publisher.put(payload, attachment=attachment)
            except zenoh.ZError:
                if self.stop_event.is_set():
                    return  # shutting down: the session is closing under us
                raise
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
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    parser.add_argument("--resolution", default="752x480", help="camera WIDTHxHEIGHT (default 752x480)")
    parser.add_argument("--hfov", type=float, default=90.0, help="horizontal field of view (deg)")
    parser.add_argument(
        "--no-rectify", action="store_true", help="VO on raw frames (the paper's traditional VO)"
    )
    add_enum_argument(
        parser, "--filter", FilterKind, FilterKind.BIAS,
        help="attitude/altitude filter: bias (error-state EKF with gyro and accel biases, default) or "
        "paper_c (paper C's 5-state EKF)",
    )  # fmt: skip
    parser.add_argument("--no-visual-yaw", action="store_true", help="do not feed the VO yaw to the EKF")
    parser.add_argument("--external-yaw", action="store_true", help="also use capataz/uav/{uav}/yaw")
    parser.add_argument("--max-lag", type=float, default=0.02, help="reordering lag of the input (s)")
    parser.add_argument("--initial-yaw", type=float, default=0.0, help="initial yaw (rad)")
    parser.add_argument(
        "--initial-xy",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("X", "Y"),
        help="initial horizontal position of the VO path (m)",
    )
    parser.add_argument(
        "--vo-origin-delay",
        type=float,
        default=0.0,
        help="seconds before the VO sets its origin (at --initial-xy)",
    )
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
