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
from dataclasses import replace

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from common.camera import CameraModel
from common.errors import InputError
from common.geometry import CameraMount, check_rotation_matrix
from common.types import FloatArray
from common.yaw.mount import image_turn_axis_imu
from common.yaw.settings import YawSettings
from services.runtime.camera_options import (
    CameraOptions,
    add_camera_options,
    camera_options_from_args,
    load_camera,
)
from services.runtime.options import add_options, flag_of, from_core
from services.runtime.usage import UsageError, condense_validation_error


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
    max_yaw_rate_deg_s: float = from_core(YawSettings, "max_yaw_rate_deg_s")
    mount: str = Field(
        default="down",
        description="how the camera sits on the body: down, forward, or R_body_camera as 9 comma-separated "
        "numbers (row-major); the gyro prior integrates about the axis the image turns about",
    )
    imu_axes: str = Field(
        default="body",
        description="the IMU's axes on the body: body, or R_body_imu as 9 comma-separated numbers "
        "(row-major; gyro_body = R_body_imu gyro_imu)",
    )
    imu_time_offset_s: float = Field(
        default=0.0,
        ge=-1.0,
        le=1.0,
        description="the IMU's clock against the camera's (s): t_imu = t_cam + offset (Kalibr's "
        "timeshift_cam_imu)",
    )

    @field_validator("mount")
    @classmethod
    def _known_mount(cls, value: str) -> str:
        mount_rotation(value, "mount")
        return value

    @field_validator("imu_axes")
    @classmethod
    def _known_axes(cls, value: str) -> str:
        mount_rotation(value, "imu_axes")
        return value

    @property
    def R_body_camera(self) -> FloatArray:
        return mount_rotation(self.mount, "mount")

    @property
    def R_body_imu(self) -> FloatArray:
        return mount_rotation(self.imu_axes, "imu_axes")

    def gyro_axis_imu(self) -> FloatArray:
        """The axis, in the IMU's axes, the gyro prior integrates about (:func:`image_turn_axis_imu`)."""
        return image_turn_axis_imu(self.R_body_camera, self.R_body_imu)

    def tracker_settings(self, base: YawSettings, camera: CameraModel | None) -> YawSettings:
        """The central stage's settings with ``camera`` (:meth:`CameraSource.at` the frames' size)."""
        return replace(base, camera=camera, max_yaw_rate_deg_s=self.max_yaw_rate_deg_s)


#: the named mounts of ``--mount`` and ``--imu-axes``
_NAMED_ROTATIONS = {**{m.value: m.R_body_camera for m in CameraMount}, "body": np.eye(3)}


def mount_rotation(spec: str, name: str) -> FloatArray:
    """A named mount (down, forward, body) or 9 comma-separated numbers (row-major) as a checked rotation;
    a ValueError naming the setting otherwise (pydantic reports it as the option's error)."""
    text = spec.strip().lower()
    if text in _NAMED_ROTATIONS:
        return np.asarray(_NAMED_ROTATIONS[text], dtype=np.float64)
    try:
        numbers = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        numbers = []
    if len(numbers) != 9:
        raise ValueError(f"{name} must be one of {sorted(_NAMED_ROTATIONS)} or 9 numbers, got {spec!r}")
    try:
        return check_rotation_matrix(np.reshape(numbers, (3, 3)), name)
    except InputError as exc:
        raise ValueError(str(exc)) from None


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
    add_options(
        parser,
        YawPriorSettings,
        ("gyro_prior", "max_yaw_rate_deg_s", "mount", "imu_axes", "imu_time_offset_s"),
    )
    add_camera_options(parser, None)


def yaw_prior_settings_from_args(args: argparse.Namespace) -> YawPriorSettings:
    """Lens, gyro prior and rate limit from the command line (one UsageError line when inconsistent); a
    calibration file is read now, so that a bad one stops the service at start."""
    lens = camera_options_from_args(args)
    try:
        prior = YawPriorSettings(
            lens=lens,
            gyro_prior=args.gyro_prior,
            max_yaw_rate_deg_s=args.max_yaw_rate_deg_s,
            mount=args.mount,
            imu_axes=args.imu_axes,
            imu_time_offset_s=args.imu_time_offset_s,
        )
    except ValidationError as exc:
        raise UsageError(condense_validation_error(exc, flag_of)) from None
    CameraSource(lens)
    return prior
