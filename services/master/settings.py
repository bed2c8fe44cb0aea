"""The master's settings and their command-line options."""

from __future__ import annotations

import argparse
from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field

from common.dispatch import Balance, DispatchSettings, SpeedSource
from common.streams import FrameGateSettings
from common.yaw import YawSettings
from services.master.lens import YawPriorSettings, add_yaw_prior_arguments, yaw_prior_settings_from_args
from services.runtime.cli import add_dispatch_arguments, add_enum_argument, dispatch_from_args, parse_size
from services.runtime.fields import settings_from


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
    #: take part in the election of the UAV's active master (off: always active, the paper's single master)
    election: bool = True
    #: newest admitted frames kept (a standby taking over measures them against the last published one)
    recent_frames: int = Field(default=8, ge=1, le=64)
    #: frames waiting for the yaw stage at most (oldest dropped beyond)
    frame_queue: int = Field(default=8, ge=1, le=256)
    max_seq_jump: int = Field(default=200, ge=1)
    confirm_frames: int = Field(default=3, ge=1, le=100)
    #: lens model, gyro prior and physical yaw-rate limit of the central stage
    prior: YawPriorSettings = YawPriorSettings()
    #: defence in depth: vet members' results against the robust fit, cap shares (see common.dispatch.trust)
    trust: bool = True

    # the stages' settings take the fields of the same name (the other fields keep their defaults)
    def gate_settings(self) -> FrameGateSettings:
        return settings_from(FrameGateSettings, self)

    def yaw_settings(self) -> YawSettings:
        return settings_from(YawSettings, self)

    def dispatch_settings(self) -> DispatchSettings:
        return settings_from(DispatchSettings, self)


def add_master_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    add_enum_argument(
        parser, "--topology", Topology, Topology.MASTER_FOREMAN_WORKER,
        help="master-worker: the master splits frames among workers; master-foreman-worker: among foremen, "
        "who split their block among their node's workers"
    )  # fmt: skip
    add_dispatch_arguments(parser, compute_help="the master computes a share itself besides its members")
    parser.add_argument("--budget-ms", type=float, default=1000.0, help="time budget of a frame's round")
    parser.add_argument("--grid", default="8x5", help="patch grid COLSxROWS (default 8x5)")
    parser.add_argument(
        "--patch-size", dest="patch_size_px", type=int, default=32, help="patch side at the pyramid level"
    )
    parser.add_argument("--pyramid-level", type=int, default=1, help="pyramid level of the patches")
    add_yaw_prior_arguments(parser)
    parser.add_argument("--trust", action=argparse.BooleanOptionalAction, default=True,
                        help="vet members, cap shares, one frame source (default on)")  # fmt: skip


def master_settings_from_args(args: argparse.Namespace) -> MasterSettings:
    cols, rows = parse_size(args.grid, "--grid", "8x5")
    return settings_from(
        MasterSettings,
        args,
        dispatch_from_args(args),
        topology=Topology(args.topology),
        budget_s=args.budget_ms / 1e3,
        grid_cols=cols,
        grid_rows=rows,
        prior=yaw_prior_settings_from_args(args),
    )
