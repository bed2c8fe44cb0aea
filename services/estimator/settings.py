"""The estimator's settings, the in-process estimator they build, and their command-line form.

The coupling's fields (rectify, filter, visual and external yaw, input lag, initial yaw and position, VO
origin delay) take their default, bound and help text from :class:`CouplingSettings`
(:func:`~services.runtime.options.from_core`) and go back to it by name (:meth:`EstimatorSettings.coupling`);
the service's own (frame backlog, VO drift, vehicle) are declared here once. The options are generated from
the fields (:func:`~services.runtime.options.add_options`), the camera's from the shared option group.
"""

from __future__ import annotations

import argparse

from pydantic import BaseModel, ConfigDict, Field

from common.camera import CameraModel
from common.estimation.coupling import DoubleCouplingEstimator
from common.estimation.coupling_types import CouplingSettings, EkfKind, Vehicle, vehicle_settings
from common.rig import Rig
from services.estimator.outputs import PublishedUncertainty
from services.runtime.camera_options import CameraOptions, load_camera
from services.runtime.fields import settings_from
from services.runtime.mount_options import MountOptions, add_rig_options, rig_options_from_args
from services.runtime.options import add_options, from_core


class EstimatorSettings(BaseModel):
    """What the estimator needs besides the transport."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = Field(default="uav0", description="UAV stream id")
    #: the camera option group's values (nothing given: the simulated camera, :meth:`CameraModel.default`)
    camera: CameraOptions = CameraOptions()
    #: the camera's mount, the IMU's axes and clock offset (the shared mount option group)
    rig_mount: MountOptions = MountOptions()
    rectify: bool = from_core(CouplingSettings, "rectify")
    filter: EkfKind = from_core(CouplingSettings, "filter")
    visual_yaw: bool = from_core(CouplingSettings, "visual_yaw")
    external_yaw: bool = from_core(CouplingSettings, "external_yaw")
    max_lag_s: float = from_core(CouplingSettings, "max_lag_s")
    initial_yaw_rad: float = from_core(CouplingSettings, "initial_yaw_rad")
    #: the initial x, y are the position when the VO sets its origin (after ``vo_origin_delay_s``; the
    #: filter's tilt settles first; paper C's flight hovers 5 s, the bench uses 4 s)
    initial_position_m: tuple[float, float] = from_core(CouplingSettings, "initial_position_m")
    vo_origin_delay_s: float = from_core(CouplingSettings, "vo_origin_delay_s")
    #: nominal horizontal drift of the VO as a fraction of the distance travelled (pose covariance only; the
    #: default model's drift grows with the pairs chained instead, :class:`PublishedUncertainty`)
    vo_drift_fraction: float = Field(default=PublishedUncertainty.drift_fraction, ge=0.0)
    #: the frame backlog when the filter is behind (:class:`~services.estimator.backlog.SpacedFrameQueue`):
    #: frames queued before one is skipped, the widest VO pair made by skipping (s; every 5th frame of
    #: paper C's 20 fps flight keeps its accuracy), and how far behind the queue may grow to keep pairs that
    #: close (s; the attitude waits for the VO too, so this bounds the latency of every output)
    frame_queue: int = Field(default=6, ge=2, le=128, description="frames queued before one is skipped")
    max_pair_s: float = Field(
        default=0.25, gt=0.0, le=10.0, description="widest VO pair (s) made by skipping frames when behind"
    )
    max_backlog_s: float = Field(  # the held samples (4096) span about 9 s
        default=3.0,
        ge=0.0,
        le=8.0,
        description="how far behind (s) the frame queue grows to keep pairs within --max-pair",
    )
    #: what the filter may assume of the vehicle: any (default) or a multirotor in still air (indoors: the
    #: thrust-axis update tells the accelerometer bias from the tilt at hover; wrong in wind)
    vehicle: Vehicle = Field(
        default=Vehicle.ANY,
        description="what the filter may assume: any or still_air_multirotor (indoors: the thrust-axis "
        "update separates the accelerometer bias from the tilt at hover; wind breaks it)",
    )

    def published_uncertainty(self) -> PublishedUncertainty:
        """How the filter's and the VO path's uncertainties are published (the drift fraction is ours)."""
        return PublishedUncertainty(drift_fraction=self.vo_drift_fraction)

    def coupling(self) -> CouplingSettings:
        """The coupling's settings: its fields of the same name, and what the vehicle sets."""
        return settings_from(CouplingSettings, self, **vehicle_settings(self.vehicle))


def estimator_camera(settings: EstimatorSettings) -> CameraModel:
    """The camera of ``settings``' camera options (a calibration file is read here); nothing given: the
    simulated camera."""
    camera = load_camera(settings.camera, CameraModel.default())
    assert camera is not None  # a default is given
    return camera


def build_estimator(settings: EstimatorSettings, rig: Rig | None = None) -> DoubleCouplingEstimator:
    """The in-process estimator the service runs (also used to check the service against): the camera and
    mount of the stream's ``rig`` when given, else of the settings' camera and mount options."""
    if rig is not None:
        camera, R_body_camera, R_body_imu, offset = (
            rig.camera, rig.R_body_camera, rig.R_body_imu, rig.time_offset_s
        )  # fmt: skip
    else:
        mount = settings.rig_mount
        camera, R_body_camera = estimator_camera(settings), mount.R_body_camera
        R_body_imu, offset = mount.R_body_imu, mount.imu_time_offset_s
    return DoubleCouplingEstimator(
        camera, R_body_camera, settings=settings.coupling(), R_body_imu=R_body_imu, imu_time_offset_s=offset
    )


def configured_rig(settings: EstimatorSettings) -> Rig:
    """The rig the settings' camera and mount options describe (the defaults: the simulated camera looking
    down, the IMU in the body's axes)."""
    mount = settings.rig_mount
    return Rig(
        estimator_camera(settings),
        mount.R_body_camera,
        R_body_imu=mount.R_body_imu,
        time_offset_s=mount.imu_time_offset_s,
    )


#: the options in the order of ``--help``; each one's default, bound and help text is its field's
_OPTIONS = (
    "uav", "rectify", "filter", "visual_yaw", "external_yaw", "max_lag_s", "initial_yaw_rad",
    "initial_position_m", "vo_origin_delay_s", "frame_queue", "max_pair_s", "max_backlog_s", "vehicle",
)  # fmt: skip


def add_estimator_arguments(parser: argparse.ArgumentParser) -> None:
    """The estimator's own command-line options (the transport's are added by the service)."""
    add_rig_options(parser, CameraModel.default())
    add_options(
        parser,
        EstimatorSettings,
        _OPTIONS,
        flags={"initial_position_m": "--initial-xy"},
        extra={"initial_position_m": {"type": float, "nargs": 2, "metavar": ("X", "Y")}},
    )


def settings_from_args(args: argparse.Namespace) -> EstimatorSettings:
    """The settings of the command line (a value out of its bound: a ValidationError, one line, exit 2)."""
    camera, mount = rig_options_from_args(args)
    settings = settings_from(EstimatorSettings, args, camera=camera, rig_mount=mount)
    estimator_camera(settings)  # a bad calibration file stops the command at start, in one line
    return settings
