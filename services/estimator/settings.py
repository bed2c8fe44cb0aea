"""The estimator's settings, the in-process estimator they build, and their command-line form."""

from __future__ import annotations

import argparse

from pydantic import BaseModel, ConfigDict, Field

from common.camera import CameraModel
from common.errors import InputError
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.coupling_types import CouplingSettings, EkfKind, Vehicle, vehicle_settings
from services.runtime.cli import add_enum_argument


class EstimatorSettings(BaseModel):
    """What the estimator needs besides the transport."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    width: int = Field(default=752, gt=0)
    height: int = Field(default=480, gt=0)
    hfov_deg: float = Field(default=90.0, gt=0.0, lt=180.0)
    rectify: bool = True
    #: the attitude/altitude filter: the bias-estimating error-state EKF (default) or paper C's 5-state EKF
    filter: EkfKind = EkfKind.BIAS
    visual_yaw: bool = True
    external_yaw: bool = False
    max_lag_s: float = Field(default=0.02, ge=0.0, le=1.0)
    initial_yaw_rad: float = 0.0
    initial_x_m: float = 0.0
    initial_y_m: float = 0.0
    #: seconds after the first frame at which the VO sets its origin (the filter's tilt settles first; paper
    #: C's flight hovers 5 s, the bench uses 4 s); the initial x, y are the position at that moment
    vo_origin_delay_s: float = Field(default=0.0, ge=0.0, le=60.0)
    #: nominal horizontal drift of the VO as a fraction of the distance travelled (pose covariance only)
    vo_drift_fraction: float = Field(default=0.001, gt=0.0)
    #: the frame backlog when the filter is behind (:class:`~services.estimator.backlog.SpacedFrameQueue`):
    #: frames queued before one is skipped, the widest VO pair made by skipping (s; every 5th frame of
    #: paper C's 20 fps flight keeps its accuracy), and how far behind the queue may grow to keep pairs that
    #: close (s; the attitude waits for the VO too, so this bounds the latency of every output)
    frame_queue: int = Field(default=6, ge=2, le=128)
    max_pair_s: float = Field(default=0.25, gt=0.0, le=10.0)
    max_backlog_s: float = Field(default=3.0, ge=0.0, le=8.0)  # the held samples (4096) span about 9 s
    #: what the filter may assume of the vehicle: any (default) or a multirotor in still air (indoors: the
    #: thrust-axis update tells the accelerometer bias from the tilt at hover; wrong in wind)
    vehicle: Vehicle = Vehicle.ANY

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
            vo_origin_delay_s=self.vo_origin_delay_s,
            **vehicle_settings(self.vehicle),
        )


def build_estimator(settings: EstimatorSettings) -> DoubleCouplingEstimator:
    """The in-process estimator the service runs (also used to check the service against)."""
    return DoubleCouplingEstimator(settings.camera(), settings=settings.coupling())


def add_estimator_arguments(parser: argparse.ArgumentParser) -> None:
    """The estimator's own command-line options (the transport's are added by the service)."""
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    parser.add_argument("--resolution", default="752x480", help="camera WIDTHxHEIGHT (default 752x480)")
    parser.add_argument("--hfov", type=float, default=90.0, help="horizontal field of view (deg)")
    parser.add_argument(
        "--no-rectify", action="store_true", help="VO on raw frames (the paper's traditional VO)"
    )
    add_enum_argument(
        parser, "--filter", EkfKind, EkfKind.BIAS,
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
    parser.add_argument(
        "--frame-queue", type=int, default=6, help="frames queued before one is skipped (default 6)"
    )
    parser.add_argument(
        "--max-pair",
        type=float,
        default=0.25,
        help="widest VO pair (s) made by skipping frames when behind (default 0.25)",
    )
    parser.add_argument(
        "--max-backlog",
        type=float,
        default=3.0,
        help="how far behind (s) the frame queue grows to keep pairs within --max-pair (default 3)",
    )
    add_enum_argument(
        parser, "--vehicle", Vehicle, Vehicle.ANY,
        help="what the filter may assume: any (default) or still_air_multirotor (indoors: the thrust-axis "
        "update separates the accelerometer bias from the tilt at hover; wind breaks it)",
    )  # fmt: skip


def settings_from_args(args: argparse.Namespace) -> EstimatorSettings:
    try:
        width, height = (int(v) for v in str(args.resolution).lower().split("x"))
        return EstimatorSettings(
            uav=args.uav,
            width=width,
            height=height,
            hfov_deg=args.hfov,
            rectify=not args.no_rectify,
            filter=EkfKind(args.filter),
            visual_yaw=not args.no_visual_yaw,
            external_yaw=args.external_yaw,
            max_lag_s=args.max_lag,
            initial_yaw_rad=args.initial_yaw,
            initial_x_m=args.initial_xy[0],
            initial_y_m=args.initial_xy[1],
            vo_origin_delay_s=args.vo_origin_delay,
            frame_queue=args.frame_queue,
            max_pair_s=args.max_pair,
            max_backlog_s=args.max_backlog,
            vehicle=Vehicle(args.vehicle),
        )
    except ValueError as exc:
        raise InputError(f"invalid estimator settings: {exc}") from None
