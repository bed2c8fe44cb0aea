"""The localizer: a particle filter against a known 3D scene, fed by a UAV's camera (paper B).

Subscribes to ``capataz/uav/{uav}/camera`` (and, with ``--use-vo``, to ``.../pose/vo``, whose successive
positions and yaws give the prediction its velocity and yaw rate) and publishes ``.../pose/pf``:
a :class:`PoseEstimate` with the particle cloud's mean and its 6x6 covariance (position, world-frame error
angles), ``source = "pf"``, the frame's ``seq`` and ``stamp_s``.

Latest frame wins: the subscriber callback only decodes and hands the frame to a one-item slot; a frame
replaced before the filter took it is counted (``dropped_frames``). Bad frames are refused with a log line
and a counter, never a crash: undecodable (``malformed``), another UAV's (``wrong_uav``), a size that is
not the camera's (``bad_frames``), a time stamp not after the previous frame's (``stale_frames``).
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict, Field

from common import keys
from common.camera import CameraModel
from common.errors import CapatazError
from common.geometry import (
    CameraMount,
    euler_from_quaternion,
    quaternion_from_euler,
    wrap_angle_rad,
)
from common.localization.model import SceneModel, default_scene, scene_from_json
from common.localization.particle_filter import (
    ParticleFilter,
    ParticleFilterSettings,
    ParticleState,
    PoseStatistics,
    covariance_with_world_error_angles,
)
from common.localization.scoring import ScoringMethod, ScoringSettings
from common.localization.simulation import DEFAULT_HEIGHT_PX, DEFAULT_HFOV_DEG, DEFAULT_WIDTH_PX
from common.localization.tracking import localizer_step
from common.messages import Frame, PoseEstimate, encode
from common.sim.scene import default_flight
from services.runtime.transport import (
    LatestSlot,
    ServiceRuntime,
    TransportSettings,
    add_transport_arguments,
    transport_from_args,
)


class LocalizerSettings(BaseModel):
    """What the localizer needs besides the transport."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    #: JSON scene file (see common.localization.model); None = the built-in office
    scene: Path | None = None
    width: int = Field(default=DEFAULT_WIDTH_PX, gt=0)
    height: int = Field(default=DEFAULT_HEIGHT_PX, gt=0)
    hfov_deg: float = Field(default=DEFAULT_HFOV_DEG, gt=0.0, lt=180.0)
    camera_mount: CameraMount = CameraMount.FORWARD
    particles: int = Field(default=200, ge=2)
    scoring: ScoringMethod = ScoringMethod.NEAREST_EDGE_DT
    seed: int = 0
    #: initial guess (x, y, z, roll, pitch, yaw) in m and rad; None = the default flight's first pose
    initial_pose: tuple[float, float, float, float, float, float] | None = None
    use_vo: bool = False

    def camera(self) -> CameraModel:
        return CameraModel.from_hfov(self.width, self.height, self.hfov_deg)

    def load_scene(self) -> SceneModel:
        if self.scene is None:
            return default_scene()
        try:
            text = self.scene.read_text()
        except OSError as exc:
            raise CapatazError(f"cannot read scene file {self.scene}: {exc}") from None
        return scene_from_json(text)

    def guess(self) -> np.ndarray:
        if self.initial_pose is None:
            return default_flight(n_frames=2).states[0]
        return np.asarray(self.initial_pose, dtype=np.float64)


def pose_message(uav: str, seq: int, stamp_s: float, estimate: PoseStatistics) -> PoseEstimate:
    """The ``pose/pf`` message of a particle-cloud estimate."""
    roll, pitch, yaw = estimate.mean[3:]
    return PoseEstimate(
        uav=uav,
        seq=seq,
        stamp_s=stamp_s,
        p_world_body_m=estimate.mean[:3].copy(),
        q_world_body=quaternion_from_euler(roll, pitch, yaw),
        covariance=covariance_with_world_error_angles(estimate.mean, estimate.covariance),
        source="pf",
    )


def odometry_between(previous: PoseEstimate, current: PoseEstimate) -> tuple[np.ndarray, np.ndarray] | None:
    """World velocity (m/s) and Euler-angle rates (rad/s) between two VO poses; None unless time advanced."""
    dt = current.stamp_s - previous.stamp_s
    if dt <= 0.0:
        return None
    velocity = (current.p_world_body_m - previous.p_world_body_m) / dt
    change = euler_from_quaternion(current.q_world_body) - euler_from_quaternion(previous.q_world_body)
    return velocity, wrap_angle_rad(change) / dt  # the angle wrap of common.geometry


class LocalizerService(ServiceRuntime):
    role = keys.Role.LOCALIZER

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        settings: LocalizerSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        super().__init__(node, index, transport, stats_period_s)
        self.settings = settings
        self.camera = settings.camera()
        mount = settings.camera_mount.R_body_camera
        config = ParticleFilterSettings(
            n_particles=settings.particles,
            scoring=ScoringSettings(method=settings.scoring),
            R_body_camera=mount.copy(),
        )
        self.filter = ParticleFilter(settings.load_scene(), self.camera, config)
        self.rng = np.random.default_rng(settings.seed)
        self.state: ParticleState = self.filter.initialize(settings.guess(), self.rng)
        self._slot: LatestSlot[Frame] = LatestSlot()
        self._last_stamp_s: float | None = None  # of the last frame the filter used
        self._last_received_s: float | None = None  # of the last frame accepted by the subscriber
        self._vo_lock = threading.Lock()
        self._vo_previous: PoseEstimate | None = None
        self._vo_velocity: np.ndarray | None = None
        self._vo_rates: np.ndarray | None = None
        self._entities: list[Any] = []

    def start(self, session: zenoh.Session) -> None:
        uav = self.settings.uav
        self._publisher = session.declare_publisher(keys.pose_pf_key(uav))
        self._entities.append(session.declare_subscriber(keys.camera_key(uav), self._on_frame))
        if self.settings.use_vo:
            self._entities.append(session.declare_subscriber(keys.pose_vo_key(uav), self._on_vo))
        self.spawn(self._localize, "localize")

    def stop(self) -> None:
        self.undeclare_all([*self._entities, getattr(self, "_publisher", None)])

    def queue_depths(self) -> dict[str, int]:
        return {"frames": self._slot.depth()}

    # -- callbacks: decode, check, hand off --------------------------------------------------------------
    def _on_frame(self, sample: zenoh.Sample) -> None:
        frame = self.decode_sample(sample, Frame)
        if frame is None:
            return
        if frame.uav != self.settings.uav:
            self.count_error(
                "wrong_uav", "frame of another UAV refused", f"{frame.uav!r} on {sample.key_expr}"
            )
            return
        if (frame.width, frame.height) != (self.camera.width, self.camera.height):
            self.count_error(
                "bad_frames",
                "frame refused",
                f"size {frame.width}x{frame.height}, the camera is {self.camera.width}x{self.camera.height}",
            )
            return
        if self._last_received_s is not None and frame.stamp_s <= self._last_received_s:
            self.count_error(
                "stale_frames", "frame refused", f"stamp {frame.stamp_s} not after {self._last_received_s}"
            )
            return
        self._last_received_s = frame.stamp_s
        self.counters.inc("frames_in")
        if self._slot.put(frame):
            self.counters.inc("dropped_frames")

    def _on_vo(self, sample: zenoh.Sample) -> None:
        pose = self.decode_sample(sample, PoseEstimate)
        if pose is None or pose.uav != self.settings.uav:
            return
        with self._vo_lock:
            previous, self._vo_previous = self._vo_previous, pose
            if previous is None:
                return
            rates = odometry_between(previous, pose)
            if rates is None:
                self.count_error(
                    "stale_vo", "VO pose refused", f"stamp {pose.stamp_s} not after {previous.stamp_s}"
                )
                return
            self._vo_velocity, self._vo_rates = rates

    # -- the filter thread ------------------------------------------------------------------------------
    def _localize(self) -> None:
        while not self.stop_event.is_set():
            frame = self._slot.take(0.1)
            if frame is None:
                continue
            dt = 0.0 if self._last_stamp_s is None else frame.stamp_s - self._last_stamp_s
            self._last_stamp_s = frame.stamp_s
            with self._vo_lock:
                velocity, rates = self._vo_velocity, self._vo_rates
            t0 = time.perf_counter()
            self.state, estimate = localizer_step(
                self.filter, self.state, frame.pixels, dt, self.rng, velocity, rates
            )
            self.counters.time_ms("step", (time.perf_counter() - t0) * 1e3)
            payload, attachment = encode(pose_message(self.settings.uav, frame.seq, frame.stamp_s, estimate))
            self._publisher.put(payload, attachment=attachment)
            self.counters.inc("poses_out")


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "localizer", help="particle-filter localization against a known 3D scene; publishes pose/pf"
    )
    add_transport_arguments(parser, node_default="localizer")
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    parser.add_argument("--scene", type=Path, help="JSON scene file (default: the built-in office)")
    parser.add_argument(
        "--resolution", default=f"{DEFAULT_WIDTH_PX}x{DEFAULT_HEIGHT_PX}", help="camera WIDTHxHEIGHT"
    )
    parser.add_argument("--hfov", type=float, default=DEFAULT_HFOV_DEG, help="horizontal field of view (deg)")
    parser.add_argument(
        "--mount",
        choices=[m.value for m in CameraMount],
        default=CameraMount.FORWARD.value,
        help="camera on the body",
    )
    parser.add_argument("--particles", type=int, default=200, help="number of particles (default 200)")
    parser.add_argument(
        "--scoring",
        choices=[m.value for m in ScoringMethod],
        default=ScoringMethod.NEAREST_EDGE_DT.value,
        help="paper B's image-closeness measure (nearest_edge_dt: nearest edge through a distance transform)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the filter's random numbers")
    parser.add_argument(
        "--initial-pose",
        type=float,
        nargs=6,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="initial guess (m, rad); default: the simulated flight's start",
    )
    parser.add_argument("--use-vo", action="store_true", help="drive the prediction by pose/vo")
    parser.set_defaults(handler=run)


def settings_from_args(args: argparse.Namespace) -> LocalizerSettings:
    try:
        width, height = (int(v) for v in args.resolution.lower().split("x"))
    except ValueError:
        raise CapatazError(f"--resolution must look like 320x240, got {args.resolution!r}") from None
    try:
        return LocalizerSettings(
            uav=args.uav,
            scene=args.scene,
            width=width,
            height=height,
            hfov_deg=args.hfov,
            camera_mount=args.mount,
            particles=args.particles,
            scoring=ScoringMethod(args.scoring),
            seed=args.seed,
            initial_pose=tuple(args.initial_pose) if args.initial_pose else None,
            use_vo=args.use_vo,
        )
    except ValueError as exc:
        raise CapatazError(f"invalid localizer settings: {exc}") from None


def run(args: argparse.Namespace) -> int:
    return LocalizerService(
        args.node, args.index, transport_from_args(args), settings_from_args(args), args.stats_period
    ).run()
