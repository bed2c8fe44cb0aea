"""The master's yaw options: its camera (the shared camera option group: a calibration file, OpenCV YAML or
ROS ``camera_info`` YAML, or explicit intrinsics and distortion), the gyro prior (the camera's mount, the
IMU's axes and clock offset: until the stream's rig carries them) and the physical yaw-rate limit, on the
command line and in the settings.

The yaw core undistorts the correspondences (patch centres and shifted centres) before its fit, so a
wide-angle lens measures the same rotation as a pinhole. A calibration made at another resolution of the
same aspect ratio is scaled to the frames; another aspect ratio is refused. Nothing given: no lens model
(an undistorted camera centred on the frame; the yaw then needs no intrinsics).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.camera import CameraModel
from common.errors import InputError
from common.rig import Rig
from common.types import FloatArray
from common.yaw.mount import image_turn_axis_imu, yaw_per_image_turn
from common.yaw.settings import YawSettings
from services.runtime.camera_options import CameraOptions, load_camera
from services.runtime.mount_options import MountOptions, add_rig_options, rig_options_from_args
from services.runtime.options import add_options, flag_of, from_core
from services.runtime.rig_follow import describe_rig
from services.runtime.usage import UsageError, condense_validation_error

logger = logging.getLogger(__name__)


class YawPriorSettings(BaseModel):
    """What the master's central stage adds to the shared yaw settings: the lens, the gyro prior, limits."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    #: the camera option group's values (nothing given: no lens model)
    lens: CameraOptions = CameraOptions()
    gyro_prior: bool = Field(
        default=True,
        description="use the stream's IMU (capataz/uav/{uav}/imu) as the yaw's prior and bridge "
        "(--no-gyro-prior: hold the recent yaw rate over untrusted pairs)",
    )
    #: how long a frame may wait for IMU samples reaching its stamp (s)
    gyro_wait_s: float = Field(default=0.05, ge=0.0, le=1.0)
    #: off by default until the window's pull is removed too: alone it leaves that bias uncovered on
    #: wide-angle low flights (docs/methods.md, "Tilt")
    level_views: bool = Field(
        default=False,
        description="fit each pair in level views by the IMU's tilt (needs a calibrated lens and the IMU): "
        "a tilted body's translation no longer reads as a turn, and the turn is the heading's",
    )
    max_yaw_rate_deg_s: float = from_core(YawSettings, "max_yaw_rate_deg_s")
    #: the camera's mount, the IMU's axes and clock offset (the shared mount option group)
    rig_mount: MountOptions = MountOptions()

    def gyro_axis_imu(self) -> FloatArray:
        """The weights, in the IMU's axes, the gyro prior integrates with (:func:`image_turn_axis_imu`)."""
        return image_turn_axis_imu(self.rig_mount.R_body_camera, self.rig_mount.R_body_imu)

    def tracker_settings(self, base: YawSettings, camera: CameraModel | None) -> YawSettings:
        """The central stage's settings with ``camera`` (:meth:`CameraSource.at` the frames' size)."""
        return replace(base, camera=camera, max_yaw_rate_deg_s=self.max_yaw_rate_deg_s)


class CameraSource:
    """The master's camera, its calibration file read once (when the service sets up): :meth:`at` gives it
    for frames of a size (explicit intrinsics centre on the frame)."""

    def __init__(self, options: CameraOptions) -> None:
        self.options = options
        self.calibrated = load_camera(options, None) if options.calibration is not None else None

    def at(self, width: int, height: int) -> CameraModel | None:
        if self.calibrated is not None:
            return self.calibrated
        return load_camera(self.options, None, (width, height))


def add_yaw_prior_arguments(parser: argparse.ArgumentParser) -> None:
    """The master's camera options (the shared group) and its yaw prior's (gyro, physical rate limit, the
    camera's mount, the IMU's axes and clock offset)."""
    add_options(parser, YawPriorSettings, ("gyro_prior", "level_views", "max_yaw_rate_deg_s"))
    add_rig_options(parser, None)


def yaw_prior_settings_from_args(args: argparse.Namespace) -> YawPriorSettings:
    """Lens, gyro prior and rate limit from the command line (one UsageError line when inconsistent); a
    calibration file is read now, so that a bad one stops the service at start."""
    lens, mount = rig_options_from_args(args)
    try:
        prior = YawPriorSettings(
            lens=lens,
            gyro_prior=args.gyro_prior,
            level_views=args.level_views,
            max_yaw_rate_deg_s=args.max_yaw_rate_deg_s,
            rig_mount=mount,
        )
    except ValidationError as exc:
        raise UsageError(condense_validation_error(exc, flag_of)) from None
    try:
        yaw_per_image_turn(prior.rig_mount.R_body_camera)
    except InputError as exc:
        raise UsageError(f"--mount: {exc}") from None
    CameraSource(lens)
    return prior


def stream_geometry(
    prior: YawPriorSettings, lens: CameraSource, width: int, height: int, rig: Rig | None, name: str = ""
) -> tuple[CameraModel | None, FloatArray, FloatArray, float, FloatArray]:
    """``(camera, R_body_camera, gyro weights in the IMU's axes, IMU clock offset, R_body_imu)`` of a stream
    of frames of ``width`` x ``height``: the stream's ``rig`` when it has one (logged for master ``name``),
    else the master's own options."""
    if rig is None:
        mount = prior.rig_mount
        camera = lens.at(width, height)
        return camera, mount.R_body_camera, prior.gyro_axis_imu(), mount.imu_time_offset_s, mount.R_body_imu
    logger.info("%s: measuring with the stream's %s", name, describe_rig(rig))
    axis = image_turn_axis_imu(rig.R_body_camera, rig.R_body_imu)
    return rig.camera, rig.R_body_camera, axis, rig.time_offset_s, rig.R_body_imu
