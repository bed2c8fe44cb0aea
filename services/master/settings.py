"""The master's settings and their command-line options."""

from __future__ import annotations

import argparse

from pydantic import BaseModel, ConfigDict, Field

from common.bounds import BoundError
from common.dispatch import DispatchSettings
from common.errors import InputError
from common.members import Topology
from common.streams import FrameGateSettings
from common.wire.frame_codec import DEFAULT_JPEG_QUALITY, MAX_JPEG_QUALITY, MIN_JPEG_QUALITY
from common.wire.jobs import JobEncoding
from common.wire.schema import MAX_BUDGET_S
from common.yaw import YawSettings
from services.master.lens import YawPriorSettings, add_yaw_prior_arguments, yaw_prior_settings_from_args
from services.runtime.cli import add_dispatch_arguments, dispatch_from_args, parse_size
from services.runtime.fields import settings_from
from services.runtime.options import add_options, from_core
from services.runtime.usage import UsageError


class MasterSettings(BaseModel):
    """The master's settings: the frame gate's and the yaw stage's defaults, bounds and help texts are the
    cores' (:class:`FrameGateSettings`, :class:`YawSettings`), the others declared here once; the command
    line is generated from them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = Field(default="uav0", description="UAV stream id")
    topology: Topology = Field(
        default=Topology.MASTER_FOREMAN_WORKER,
        description="master-worker: the master splits frames among workers; master-foreman-worker: among "
        "foremen, who split their block among their node's workers",
    )
    #: how its dispatcher shares a frame's patches among the members (as a foreman's does a block's)
    dispatch: DispatchSettings = Field(default_factory=DispatchSettings)
    #: time budget of one frame's round (s); shares that miss it are re-dispatched
    budget_s: float = Field(default=1.0, gt=0.0, le=MAX_BUDGET_S)
    #: the yaw stage (patch grid, patch size, pyramid level; the correlation's constants)
    yaw: YawSettings = Field(default_factory=YawSettings)
    #: take part in the election of the UAV's active master (off: always active, the paper's single master)
    election: bool = True
    #: newest admitted frames kept (a standby taking over measures them against the last published one)
    recent_frames: int = Field(default=8, ge=1, le=64)
    #: frames waiting for the yaw stage at most (oldest dropped beyond)
    frame_queue: int = Field(default=8, ge=1, le=256)
    max_seq_jump: int = from_core(FrameGateSettings, "max_seq_jump")
    confirm_frames: int = from_core(FrameGateSettings, "confirm_frames")
    #: lens model, gyro prior and physical yaw-rate limit of the central stage
    prior: YawPriorSettings = YawPriorSettings()
    trust: bool = Field(
        default=True,
        description="defence in depth: vet members' results against the robust fit, cap shares, one frame "
        "source (see common.dispatch.trust)",
    )
    refine_on_members_pixels: int = Field(
        default=2**17,
        ge=0,
        le=2**40,
        description="a turning frame's second pass (the refinement) may go to the members that measured its "
        "patches when it covers at least this many level pixels, else the master measures it (a round trip "
        "then costs more latency than it saves: the defaults' 40 patches of 32 px, 41k px, took 4.8 ms "
        "longer a frame for 1.5 ms less of the master's CPU); with --compute a larger pass goes where it has "
        "cost less, measured (common.dispatch.refine_place: 48 patches of 128 px, 786k px, saved one master "
        "40 ms and cost another, 3 times faster over 100 Mbit, more than that); without, to the members; 0: "
        "every pass may go",
    )
    job_encoding: JobEncoding = Field(
        default="mono8",
        description="how a share's pixels travel: mono8 (raw: one band of the frame where patches overlap "
        "and that is fewer bytes, else the crops), zstd (lossless, every share packed and compressed, "
        "about half the bytes for about 1 ms of CPU a share: members across a thin link) or jpeg (lossy, "
        "quality 90: about half of zstd's bytes; the members' shifts differ from the master's by the "
        "codec's error, 0.004 px median on a 1080p hover)",
    )
    job_quality: int = Field(
        default=DEFAULT_JPEG_QUALITY,
        ge=MIN_JPEG_QUALITY,
        le=MAX_JPEG_QUALITY,
        description="JPEG quality of a share with --job-encoding jpeg (1-100): 75 sends 0.59-0.74 of 90's "
        "bytes (a rendered 1080p hover; the dispatch bench's frames) and its shifts are the lossless ones "
        "within 0.056 px (median 0.012; 90: 0.016 and 0.004): for a link whose time is a frame's bound",
    )

    def gate_settings(self) -> FrameGateSettings:
        """The frame gate with the bounds of the same name (the others keep their defaults)."""
        return settings_from(FrameGateSettings, self)


def add_master_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(parser, MasterSettings, ("uav", "topology"))
    add_dispatch_arguments(parser, compute_help="the master computes a share itself besides its members")
    budget_s = MasterSettings.model_fields["budget_s"].default
    parser.add_argument(
        "--budget-ms", type=float, default=1e3 * budget_s, help="time budget of a frame's round (ms)"
    )
    yaw = YawSettings()
    grid = f"{yaw.grid_cols}x{yaw.grid_rows}"
    parser.add_argument("--grid", default=grid, help="patch grid COLSxROWS")
    add_options(
        parser, YawSettings, ("patch_size_px", "pyramid_level"), flags={"patch_size_px": "--patch-size"}
    )
    add_yaw_prior_arguments(parser)
    add_options(parser, MasterSettings, ("trust", "job_encoding", "job_quality", "refine_on_members_pixels"))


#: the master's options that set a yaw settings field whose name is not the option's
_YAW_OPTIONS = {
    "grid_cols": "--grid (columns)",
    "grid_rows": "--grid (rows)",
    "patch_size_px": "--patch-size",
}


def _yaw_option_error(exc: InputError) -> str:
    """A yaw settings error named by its option (``--grid (columns): must be ...``); a rule between fields
    names the yaw options together."""
    if isinstance(exc, BoundError):
        return f"{_YAW_OPTIONS.get(exc.field, '--' + exc.field.replace('_', '-'))}: {exc.reason}"
    return f"yaw options (--grid, --patch-size, --pyramid-level): {exc}"


def master_settings_from_args(args: argparse.Namespace) -> MasterSettings:
    """The settings of the command line (a value out of its bound: one line, exit 2)."""
    cols, rows = parse_size(args.grid, "--grid", "8x5")
    prior = yaw_prior_settings_from_args(args)
    if not 0.0 < args.budget_ms <= 1e3 * MAX_BUDGET_S:
        raise UsageError(f"--budget-ms: must be in (0, {1e3 * MAX_BUDGET_S:.0f}] ms, got {args.budget_ms}")
    try:
        # --patch-size and --pyramid-level carry the yaw settings' field names
        yaw = settings_from(YawSettings, args, grid_cols=cols, grid_rows=rows)
    except InputError as exc:
        raise UsageError(_yaw_option_error(exc)) from None
    return settings_from(
        MasterSettings,
        args,
        topology=Topology(args.topology),
        dispatch=dispatch_from_args(args),
        budget_s=args.budget_ms / 1e3,
        yaw=yaw,
        prior=prior,
    )
