"""The estimator: paper C's EKF with visual odometry and double coupling, for one UAV's streams.

Subscribes to ``capataz/uav/{uav}/imu``, ``.../range``, ``.../camera`` (and, with ``--external-yaw``, to
``.../yaw`` of the yaw cluster) and publishes

- ``capataz/uav/{uav}/attitude``: an :class:`AttitudeEstimate` after every IMU sample (the EKF's attitude,
  3x3 world-frame error-angle covariance);
- ``capataz/uav/{uav}/pose/vo``: a :class:`PoseEstimate` after every frame (x, y from the visual odometry,
  z and attitude from the EKF), ``source = "vo"``.

Callbacks only decode, validate and hand off, on zenoh's receiving thread in arrival order: IMU, range and
yaw samples to a bounded FIFO (refusals counted as ``queue_full``), frames to a one-item slot (latest frame
wins, ``dropped_frames``). One thread feeds them to
:class:`~common.estimation.coupling.DoubleCouplingEstimator`, which applies them in stamp order within a
bounded lag. Bad samples are refused with a log line and a counter, never a crash:
undecodable (``malformed``), another UAV's (``wrong_uav``), NaN/inf or a wrong shape (``bad_samples``,
``bad_frames``), stale or duplicate stamps (``refused_<sensor>_<stale|duplicate|overflow>``).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common import keys
from common.camera import CameraModel
from common.errors import InputError
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.coupling_types import (
    AttitudeOutput,
    CouplingSettings,
    FilterKind,
    PoseOutput,
)
from common.estimation.measurements import Measurement, check_frame, check_imu, check_range, check_yaw
from common.messages import AttitudeEstimate, Frame, ImuSample, PoseEstimate, RangeSample, YawEstimate, encode
from services.runtime.transport import (
    LatestSlot,
    ServiceRuntime,
    TransportSettings,
    WorkQueue,
    add_transport_arguments,
    transport_from_args,
)

SENSOR_QUEUE = 4096


class EstimatorSettings(BaseModel):
    """What the estimator needs besides the transport."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    width: int = Field(default=752, gt=0)
    height: int = Field(default=480, gt=0)
    hfov_deg: float = Field(default=90.0, gt=0.0, lt=180.0)
    rectify: bool = True
    #: the attitude/altitude filter: the bias-estimating error-state EKF (default) or paper C's 5-state EKF
    filter: FilterKind = FilterKind.BIAS
    visual_yaw: bool = True
    external_yaw: bool = False
    max_lag_s: float = Field(default=0.02, ge=0.0, le=1.0)
    initial_yaw_rad: float = 0.0
    initial_x_m: float = 0.0
    initial_y_m: float = 0.0
    #: nominal horizontal drift of the VO as a fraction of the distance travelled (pose covariance only)
    vo_drift_fraction: float = Field(default=0.001, gt=0.0)

    def camera(self) -> CameraModel:
        return CameraModel.from_hfov(self.width, self.height, self.hfov_deg)

    def coupling(self) -> CouplingSettings:
        return CouplingSettings(
            rectify=self.rectify,
            filter=self.filter,
            visual_yaw=self.visual_yaw,
            external_yaw=self.external_yaw,
            max_lag_s=self.max_lag_s,
            initial_yaw_rad=self.initial_yaw_rad,
            initial_position_m=(self.initial_x_m, self.initial_y_m),
        )


def build_estimator(settings: EstimatorSettings) -> DoubleCouplingEstimator:
    """The in-process estimator the service runs (also used to check the service against)."""
    return DoubleCouplingEstimator(settings.camera(), settings=settings.coupling())


def attitude_message(uav: str, seq: int, out: AttitudeOutput) -> AttitudeEstimate:
    """The ``attitude`` message of one filter output, with that output's own covariance."""
    return AttitudeEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        q_world_body=out.q_world_body.copy(),
        covariance=out.attitude_covariance_world.copy(),
    )


def pose_message(uav: str, seq: int, out: PoseOutput, var_xy: float) -> PoseEstimate:
    """The ``pose/vo`` message of one frame (the filter's altitude and attitude covariance at that frame)."""
    cov = np.zeros((6, 6))
    cov[0, 0] = cov[1, 1] = var_xy
    cov[2, 2] = out.altitude_var_m2
    cov[3:, 3:] = out.attitude_covariance_world
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=out.stamp_s,
        p_world_body_m=out.p_world_body_m.copy(),
        q_world_body=out.q_world_body.copy(),
        covariance=cov,
        source="vo",
    )


class EstimatorService(ServiceRuntime):
    role = keys.Role.ESTIMATOR

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        settings: EstimatorSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        super().__init__(node, index, transport, stats_period_s)
        self.settings = settings
        self.estimator = build_estimator(settings)
        self._shape = self.estimator.camera.shape
        self._samples: WorkQueue[Measurement] = WorkQueue(SENSOR_QUEUE)
        self._frames: LatestSlot[Measurement] = LatestSlot()
        self._entities: list[Any] = []
        self._mirrored: dict[str, int] = {}
        self._attitude_seq = 0
        self._pose_seq = 0
        self._travelled_m = 0.0
        self._last_xy: np.ndarray | None = None

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
        self.undeclare_all(
            [*self._entities, getattr(self, "_attitude_pub", None), getattr(self, "_pose_pub", None)]
        )

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
            return False
        return True

    def _offer(self, measurement: Measurement) -> None:
        if not self._samples.offer(measurement):
            self.count_error("queue_full", "sample refused", "the sensor queue is full")

    def _on_imu(self, sample: zenoh.Sample) -> None:
        msg = self.decode_sample(sample, ImuSample)
        if msg is None or not self._own(msg.uav, "IMU sample", sample.key_expr):
            return
        try:
            self._offer(check_imu(msg.stamp_s, msg.gyro_rad_s, msg.accel_m_s2))
        except InputError as exc:
            self.count_error("bad_samples", "IMU sample refused", exc)

    def _on_range(self, sample: zenoh.Sample) -> None:
        msg = self.decode_sample(sample, RangeSample)
        if msg is None or not self._own(msg.uav, "range sample", sample.key_expr):
            return
        try:
            self._offer(check_range(msg.stamp_s, msg.range_m))
        except InputError as exc:
            self.count_error("bad_samples", "range sample refused", exc)

    def _on_yaw(self, sample: zenoh.Sample) -> None:
        msg = self.decode_sample(sample, YawEstimate)
        if msg is None or not self._own(msg.uav, "yaw", sample.key_expr):
            return
        if msg.low_confidence:
            self.counters.inc("yaw_low_confidence")
            return
        try:
            self._offer(check_yaw(msg.stamp_s, msg.yaw_rad))
        except InputError as exc:
            self.count_error("bad_samples", "yaw refused", exc)

    def _on_frame(self, sample: zenoh.Sample) -> None:
        msg = self.decode_sample(sample, Frame)
        if msg is None or not self._own(msg.uav, "frame", sample.key_expr):
            return
        try:
            frame = check_frame(msg.stamp_s, msg.pixels, self._shape)
        except InputError as exc:
            self.count_error("bad_frames", "frame refused", exc)
            return
        self.counters.inc("frames_in")
        if self._frames.put(frame):
            self.counters.inc("dropped_frames")

    # -- the estimator thread ------------------------------------------------------------------------
    def _push(self, measurement: Measurement) -> None:
        refusal = self.estimator.push(measurement)
        if refusal is not None:
            name = type(measurement).__name__.removesuffix("Measurement").lower()
            self.count_error(
                f"refused_{name}_{refusal.value}",
                "sample refused",
                f"{refusal.value} stamp {measurement.stamp_s}",
            )

    def _estimate(self) -> None:
        while not self.stop_event.is_set():
            first = self._samples.take(0.02)
            batch = [] if first is None else [first, *self._samples.drain()]
            frame = self._frames.take(0.0)
            for m in batch:
                self._push(m)
            if frame is not None:
                self._push(frame)
            if not batch and frame is None:
                continue
            t0 = time.perf_counter()
            outputs = self.estimator.process_due()
            process_ms = (time.perf_counter() - t0) * 1e3
            self.counters.time_ms("process", process_ms)
            if any(isinstance(out, PoseOutput) for out in outputs):
                # a frame's VO step (rectification included) and the few IMU samples applied with it
                self.counters.time_ms("vo", process_ms)
            self._publish(outputs)
            self._mirror_counters()

    def _publish(self, outputs: list[AttitudeOutput | PoseOutput]) -> None:
        for out in outputs:
            if isinstance(out, AttitudeOutput):
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
            publisher.put(payload, attachment=attachment)
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
    parser.add_argument(
        "--filter",
        choices=[kind.value for kind in FilterKind],
        default=FilterKind.BIAS.value,
        help="attitude/altitude filter: bias (error-state EKF with gyro and accel biases, default) or "
        "paper_c (paper C's 5-state EKF)",
    )
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
    parser.set_defaults(handler=run)


def settings_from_args(args: argparse.Namespace) -> EstimatorSettings:
    try:
        width, height = (int(v) for v in str(args.resolution).lower().split("x"))
        return EstimatorSettings(
            uav=args.uav,
            width=width,
            height=height,
            hfov_deg=args.hfov,
            rectify=not args.no_rectify,
            filter=FilterKind(args.filter),
            visual_yaw=not args.no_visual_yaw,
            external_yaw=args.external_yaw,
            max_lag_s=args.max_lag,
            initial_yaw_rad=args.initial_yaw,
            initial_x_m=args.initial_xy[0],
            initial_y_m=args.initial_xy[1],
        )
    except ValueError as exc:
        raise InputError(f"invalid estimator settings: {exc}") from None


def run(args: argparse.Namespace) -> int:
    service = EstimatorService(
        args.node, args.index, transport_from_args(args), settings_from_args(args), args.stats_period
    )
    return service.run()
