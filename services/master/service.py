"""The master of one UAV stream: latest frame -> shares -> merged measurement -> yaw.

Topology is a setting: ``master-worker`` (members = every worker) or ``master-foreman-worker``
(members = foremen, each splitting its block among its workers). Balancing and self-compute are the
:class:`~common.dispatch.Dispatcher`'s settings. With no members at all the master computes alone.
The central stage is the yaw core's own ``YawTracker.conclude``, fed the merged measurement, so the
published yaw equals the in-process tracker's when no frame is dropped.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import zenoh
from pydantic import BaseModel, ConfigDict

from common import keys
from common.dispatch import SELF, Balance, Dispatcher, DispatchSettings, SpeedSource
from common.errors import CapatazError
from common.messages import BlockJob, BlockResult, Frame, PatchJob, PatchResult, YawEstimate, encode
from common.yaw import PatchGrid, TrackerState, YawSettings, YawTracker, make_patch_grid
from common.yaw.grid import U8Array
from common.yaw.patchwork import SpectrumCache, measure_share, merge_measurements, settings_to_wire
from services.runtime.guard import DispatchGuard
from services.runtime.membership import LiveMembers
from services.runtime.scatter import FrameWork, Scatter, add_dispatch_arguments
from services.runtime.transport import (
    LatestSlot,
    ServiceRuntime,
    TransportSettings,
    add_transport_arguments,
    transport_from_args,
)


class Topology(StrEnum):
    MASTER_WORKER = "master-worker"
    MASTER_FOREMAN_WORKER = "master-foreman-worker"


class MasterSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    topology: Topology = Topology.MASTER_FOREMAN_WORKER
    balance: Balance = Balance.TIME
    self_compute: bool = False
    speed_source: SpeedSource = SpeedSource.ROUND_TRIP
    #: time budget of one frame's round (s); shares that miss it are re-dispatched
    budget_s: float = 1.0
    min_deadline_s: float = 0.3
    grid_cols: int = 8
    grid_rows: int = 5
    patch_size_px: int = 32
    pyramid_level: int = 1
    #: defence in depth: vet members' results against the robust fit, cap shares (see common.dispatch.trust)
    trust: bool = True

    def yaw_settings(self) -> YawSettings:
        return YawSettings(
            grid_cols=self.grid_cols,
            grid_rows=self.grid_rows,
            patch_size_px=self.patch_size_px,
            pyramid_level=self.pyramid_level,
        )

    def dispatch_settings(self) -> DispatchSettings:
        return DispatchSettings(
            balance=self.balance,
            self_compute=self.self_compute,
            min_deadline_s=self.min_deadline_s,
            speed_source=self.speed_source,
        )


@dataclass
class _Stream:
    grid: PatchGrid
    tracker: YawTracker
    state: TrackerState
    prev_seq: int
    prev_level: U8Array
    dispatcher: Dispatcher
    cache: SpectrumCache = field(default_factory=SpectrumCache)


class MasterService(ServiceRuntime):
    role = keys.Role.MASTER

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        settings: MasterSettings,
        stats_period_s: float = 1.0,
    ) -> None:
        super().__init__(node, index, transport, stats_period_s)
        self.settings = settings
        self.yaw_settings = settings.yaw_settings()
        self.wire_settings = settings_to_wire(self.yaw_settings)
        self.slot: LatestSlot[Frame] = LatestSlot()
        self.stream: _Stream | None = None
        self.scatter: Scatter | None = None
        self.live = LiveMembers(self.member_role)
        #: defence in depth: trust vetting, one frame source, liveliness churn limited per key
        self.guard = DispatchGuard(self.name, self.counters, settings.trust)
        self._entities: list[Any] = []
        self._publisher: Any = None
        self._last_seq = -1
        self.gaps = 0
        self._last_shares: dict[str, float] = {}

    # -- wiring -----------------------------------------------------------------------------------------
    def start(self, session: zenoh.Session) -> None:
        self._publisher = session.declare_publisher(keys.yaw_key(self.settings.uav))
        self._entities.append(self._publisher)
        self._entities.append(
            session.liveliness().declare_subscriber(keys.ALIVE_ALL, self._on_alive, history=True)
        )
        self._entities.append(session.declare_subscriber(keys.camera_key(self.settings.uav), self._on_frame))
        self.spawn(self._serve, "frames")

    @property
    def member_role(self) -> keys.Role:
        return keys.Role.WORKER if self.settings.topology is Topology.MASTER_WORKER else keys.Role.FOREMAN

    def _on_alive(self, sample: zenoh.Sample) -> None:
        event = self.member_event(sample)
        if event is not None:
            member, joined = event
            self.guard.note_alive(member.name, joined)
            self.live.on_event(member, joined, self.counters, self.scatter)

    def _on_frame(self, sample: zenoh.Sample) -> None:
        if not self.guard.admit_frame(sample):
            return
        frame = self.decode_sample(sample, Frame)
        if frame is None:
            return
        self.counters.inc("frames_in")
        if self.slot.put(frame):
            self.counters.inc("frames_dropped")

    def _apply_membership(self, dispatcher: Dispatcher) -> None:
        self.live.update(dispatcher)  # nothing to do unless a liveliness token came or went
        self.guard.apply_quarantine(dispatcher.trust)  # members whose liveliness churns are paused

    def shares(self) -> dict[str, float]:
        return dict(self._last_shares)

    def queue_depths(self) -> dict[str, int]:
        return {"frames": self.slot.depth()}

    # -- frames -----------------------------------------------------------------------------------------
    def _serve(self) -> None:
        assert self.session is not None
        job_type: type[PatchJob] = PatchJob if self.settings.topology is Topology.MASTER_WORKER else BlockJob
        result_type: type[PatchResult] = (
            PatchResult if self.settings.topology is Topology.MASTER_WORKER else BlockResult
        )
        while not self.stop_event.is_set():
            frame = self.slot.take(0.1)
            if frame is None:
                continue
            t0 = time.perf_counter()
            try:
                estimate = self._estimate(frame, job_type, result_type, t0)
            except (CapatazError, ValueError) as exc:
                self.count_error("frame_errors", f"frame {frame.seq} failed", exc)
                continue
            payload, attachment = encode(estimate)
            self._publisher.put(payload, attachment=attachment)
            self.counters.inc("yaw_out")
            self.counters.time_ms("frame", estimate.timings_ms["total"])

    def _new_stream(self, frame: Frame) -> _Stream:
        grid = make_patch_grid((frame.height, frame.width), self.yaw_settings)
        tracker = YawTracker(self.yaw_settings, grid)
        state = tracker.initial_state(frame.pixels, with_spectra=False)
        dispatcher = Dispatcher(self.settings.dispatch_settings(), grid.n_patches)
        dispatcher.trust = self.guard.monitor()
        return _Stream(grid, tracker, state, frame.seq, grid.level_image(frame.pixels), dispatcher)

    def _estimate(
        self, frame: Frame, job_type: type[PatchJob], result_type: type[PatchResult], t0: float
    ) -> YawEstimate:
        assert self.session is not None
        if self._last_seq >= 0 and frame.seq > self._last_seq + 1:
            self.gaps += frame.seq - self._last_seq - 1
        stream = self.stream
        if (
            stream is None
            or stream.grid.frame_shape != (frame.height, frame.width)
            or frame.seq <= stream.prev_seq
        ):
            stream = self.stream = self._new_stream(frame)
            self.scatter = Scatter(
                self.session, stream.dispatcher, keys.work_key_of, job_type, result_type, self.counters
            )
            self._last_seq = frame.seq
            return YawEstimate(
                uav=self.settings.uav,
                seq=frame.seq,
                stamp_s=frame.stamp_s,
                delta_yaw_rad=0.0,
                yaw_rad=0.0,
                inlier_count=0,
                patch_count=0,
                confidence=0.0,
                low_confidence=True,
                method="initial",
                timings_ms={"total": (time.perf_counter() - t0) * 1e3},
                dropped_frames=self.slot.dropped + self.gaps,
            )
        assert self.scatter is not None
        self._apply_membership(stream.dispatcher)
        grid, settings = stream.grid, self.yaw_settings
        level = grid.level_image(frame.pixels)
        prev_level, prev_seq = stream.prev_level, stream.prev_seq
        t_level = time.perf_counter()

        def crops(indices: np.ndarray) -> np.ndarray:
            return grid.crop_level(level, indices)

        def prev_crops(indices: np.ndarray) -> np.ndarray:
            return grid.crop_level(prev_level, indices)

        def compute_self(indices: np.ndarray, moved: np.ndarray) -> Any:
            return measure_share(
                stream.cache,
                settings,
                self.settings.uav,
                frame.seq,
                prev_seq,
                indices,
                crops(indices),
                moved,
                prev_crops(moved),
            )

        work = FrameWork(
            stream=self.settings.uav,
            seq=frame.seq,
            prev_seq=prev_seq,
            settings=self.wire_settings,
            budget_s=self.settings.budget_s,
            crops=crops,
            prev_crops=prev_crops,
            compute_self=compute_self,
        )
        plan = stream.dispatcher.plan(frame.seq, prev_seq, time.monotonic())
        try:
            report = self.scatter.run(work, plan)
            measurement = merge_measurements(report.parts, grid.all_indices)
        except (CapatazError, ValueError) as exc:  # never lose a frame: compute it here
            self.count_error("local_fallback", f"frame {frame.seq}: round failed, computing locally", exc)
            stream.dispatcher.forget_history(SELF)
            measurement = compute_self(grid.all_indices, grid.all_indices)
            report = None
        t_round = time.perf_counter()
        if report is not None:
            self.guard.vet(
                stream.dispatcher.trust, report.owners, report.parts, measurement, grid.centres_px, settings
            )
        stream.state, core = stream.tracker.conclude(stream.state, frame.pixels, measurement)
        stream.prev_level, stream.prev_seq = level, frame.seq
        self._last_seq = frame.seq
        t_end = time.perf_counter()
        self._last_shares = plan.shares()
        members = report.members if report else {SELF: grid.n_patches}
        timings = {
            "total": (t_end - t0) * 1e3,
            "level": (t_level - t0) * 1e3,
            "round": (t_round - t_level) * 1e3,
            "conclude": (t_end - t_round) * 1e3,
        }
        if report is not None:
            timings["self"] = report.self_s * 1e3
        return YawEstimate(
            uav=self.settings.uav,
            seq=frame.seq,
            stamp_s=frame.stamp_s,
            delta_yaw_rad=float(core.delta_yaw_rad),
            yaw_rad=float(core.yaw_rad),
            inlier_count=int(core.inlier_count),
            patch_count=int(core.patch_count),
            confidence=float(core.confidence) if np.isfinite(core.confidence) else 0.0,
            low_confidence=bool(core.low_confidence),
            method=core.method.name.lower(),
            timings_ms=timings,
            members=members,
            speeds_patches_s=dict(report.speeds) if report else {},
            dropped_frames=self.slot.dropped + self.gaps,
            redispatched=report.redispatched if report else 0,
        )


def add_master_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    parser.add_argument(
        "--topology",
        choices=[t.value for t in Topology],
        default=Topology.MASTER_FOREMAN_WORKER.value,
        help="master-worker: the master splits frames among workers; master-foreman-worker: among foremen, "
        "who split their block among their node's workers",
    )
    add_dispatch_arguments(parser, compute_help="the master computes a share itself besides its members")
    parser.add_argument("--budget-ms", type=float, default=1000.0, help="time budget of a frame's round")
    parser.add_argument("--grid", default="8x5", help="patch grid COLSxROWS (default 8x5)")
    parser.add_argument("--patch-size", type=int, default=32, help="patch side at the pyramid level")
    parser.add_argument("--pyramid-level", type=int, default=1, help="pyramid level of the patches")
    parser.add_argument("--trust", action=argparse.BooleanOptionalAction, default=True,
                        help="vet members, cap shares, one frame source (default on)")  # fmt: skip


def master_settings_from_args(args: argparse.Namespace) -> MasterSettings:
    try:
        cols, rows = (int(v) for v in args.grid.lower().split("x"))
    except ValueError:
        raise CapatazError(f"--grid must look like 8x5, got {args.grid!r}") from None
    return MasterSettings(
        uav=args.uav,
        topology=Topology(args.topology),
        balance=Balance(args.balance),
        self_compute=args.compute,
        speed_source=SpeedSource(args.speed),
        budget_s=args.budget_ms / 1e3,
        min_deadline_s=args.min_deadline_ms / 1e3,
        grid_cols=cols,
        grid_rows=rows,
        patch_size_px=args.patch_size,
        pyramid_level=args.pyramid_level,
        trust=args.trust,
    )


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "master", help="a master: splits each frame of a UAV stream and publishes yaw"
    )
    add_transport_arguments(parser)
    add_master_arguments(parser)
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    return MasterService(
        args.node, args.index, transport_from_args(args), master_settings_from_args(args), args.stats_period
    ).run()
