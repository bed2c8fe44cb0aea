"""The master's settings and their command-line options."""

from __future__ import annotations

import argparse

from pydantic import BaseModel, ConfigDict, Field

from common.dispatch import DispatchSettings
from common.members import Topology
from common.streams import FrameGateSettings
from common.yaw import YawSettings
from services.master.lens import YawPriorSettings, add_yaw_prior_arguments, yaw_prior_settings_from_args
from services.runtime.cli import add_dispatch_arguments, add_enum_argument, dispatch_from_args, parse_size
from services.runtime.fields import settings_from


class MasterSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    topology: Topology = Topology.MASTER_FOREMAN_WORKER
    #: how its dispatcher shares a frame's patches among the members (as a foreman's does a block's)
    dispatch: DispatchSettings = Field(default_factory=DispatchSettings)
    #: time budget of one frame's round (s); shares that miss it are re-dispatched
    budget_s: float = 1.0
    #: the yaw stage (patch grid, patch size, pyramid level; the correlation's constants)
    yaw: YawSettings = Field(default_factory=YawSettings)
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

    def gate_settings(self) -> FrameGateSettings:
        """The frame gate with the bounds of the same name (the others keep their defaults)."""
        return settings_from(FrameGateSettings, self)


def add_master_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    add_enum_argument(
        parser, "--topology", Topology, Topology.MASTER_FOREMAN_WORKER,
        help="master-worker: the master splits frames among workers; master-foreman-worker: among foremen, "
        "who split their block among their node's workers"
    )  # fmt: skip
    add_dispatch_arguments(parser, compute_help="the master computes a share itself besides its members")
    parser.add_argument("--budget-ms", type=float, default=1000.0, help="time budget of a frame's round")
    yaw = YawSettings()  # the defaults have one home
    grid = f"{yaw.grid_cols}x{yaw.grid_rows}"
    parser.add_argument("--grid", default=grid, help=f"patch grid COLSxROWS (default {grid})")
    parser.add_argument(
        "--patch-size",
        dest="patch_size_px",
        type=int,
        default=yaw.patch_size_px,
        help=f"patch side at the pyramid level (default {yaw.patch_size_px})",
    )
    parser.add_argument(
        "--pyramid-level", type=int, default=yaw.pyramid_level,
        help=f"pyramid level of the patches (default {yaw.pyramid_level})",
    )  # fmt: skip
    add_yaw_prior_arguments(parser)
    parser.add_argument("--trust", action=argparse.BooleanOptionalAction, default=True,
                        help="vet members, cap shares, one frame source (default on)")  # fmt: skip


def master_settings_from_args(args: argparse.Namespace) -> MasterSettings:
    cols, rows = parse_size(args.grid, "--grid", "8x5")
    return settings_from(
        MasterSettings,
        args,
        topology=Topology(args.topology),
        dispatch=dispatch_from_args(args),
        budget_s=args.budget_ms / 1e3,
        # --patch-size and --pyramid-level carry the yaw settings' field names
        yaw=settings_from(YawSettings, args, grid_cols=cols, grid_rows=rows),
        prior=yaw_prior_settings_from_args(args),
    )
