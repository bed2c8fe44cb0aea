"""One option group for how the sensors sit on the body, until the stream's rig carries it: the camera's
mount (``--mount down|forward`` or ``R_body_camera`` as 9 numbers), the IMU's axes (``--imu-axes body`` or
``R_body_imu`` as 9 numbers) and the IMU's clock offset (``--imu-time-offset``, ``t_imu = t_cam + offset``,
Kalibr's ``timeshift_cam_imu``). The master's gyro prior and the estimator read them. A ``--calibration`` rig
file that carries a mount (the capataz rig YAML, EuRoC's ``T_BS``, Kalibr's ``T_cam_imu``) gives it instead
(:func:`mount_of_calibration`); a mount given both ways is refused. :func:`add_rig_options` and
:func:`rig_options_from_args` are the one rig option group (this and the camera's) of the master and the
estimator.
"""

from __future__ import annotations

import argparse

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from common.camera import CameraModel
from common.datasets.rig_files import load_rig
from common.errors import InputError
from common.geometry import CameraMount, check_rotation_matrix
from common.rig import Rig
from common.types import FloatArray
from services.runtime.camera_options import CameraOptions, add_camera_options, camera_options_from_args
from services.runtime.options import add_options, flag_of
from services.runtime.usage import UsageError, condense_validation_error

#: the named rotations of ``--mount`` (the camera's) and ``--imu-axes`` (the IMU's: ``body``)
NAMED_ROTATIONS = {**{m.value: m.R_body_camera for m in CameraMount}, "body": np.eye(3)}


def mount_rotation(spec: str, name: str) -> FloatArray:
    """A named rotation (down, forward, body) or 9 comma-separated numbers (row-major) as a checked rotation;
    a ValueError naming the setting otherwise (pydantic reports it as the option's error)."""
    text = spec.strip().lower()
    if text in NAMED_ROTATIONS:
        return np.array(NAMED_ROTATIONS[text], dtype=np.float64)
    try:
        numbers = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        numbers = []
    if len(numbers) != 9:
        raise ValueError(f"{name} must be one of {sorted(NAMED_ROTATIONS)} or 9 numbers, got {spec!r}")
    try:
        return check_rotation_matrix(np.reshape(numbers, (3, 3)), name)
    except InputError as exc:
        raise ValueError(str(exc)) from None


class MountOptions(BaseModel):
    """The camera's mount, the IMU's axes and clock offset, as given on the command line."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    mount: str = Field(
        default="down",
        description="how the camera sits on the body: down, forward, or R_body_camera as 9 comma-separated "
        "numbers (row-major; --mount=-0.17,... when the first is negative)",
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

    def describe(self) -> str:
        """One log line's worth: what is used."""
        return (
            f"mount {self.mount}, IMU axes {self.imu_axes}, IMU clock offset {self.imu_time_offset_s:+.4f} s"
        )


_NAMES = ("mount", "imu_axes", "imu_time_offset_s")


def add_mount_options(parser: argparse.ArgumentParser) -> None:
    """``--mount``, ``--imu-axes``, ``--imu-time-offset`` (defaults, help texts: :class:`MountOptions`)."""
    add_options(parser, MountOptions, _NAMES)


def mount_options_from_args(args: argparse.Namespace) -> MountOptions:
    """The group's values (a bad one: one UsageError line naming its option)."""
    try:
        return MountOptions(**{name: getattr(args, name) for name in _NAMES})
    except ValidationError as exc:
        raise UsageError(condense_validation_error(exc, flag_of)) from None


def mount_of_calibration(camera: CameraOptions, mount: MountOptions) -> MountOptions:
    """The mount a service uses: ``mount`` as given, or, when it is the default, the mount the
    ``--calibration`` rig file carries. A file whose mount is not the default together with mount options:
    one UsageError line (the mount would be given twice). A bad file raises its RigFileError."""
    if camera.calibration is None:
        return mount
    rig = load_rig(camera.calibration)
    default = Rig(rig.camera)
    if (
        np.array_equal(rig.R_body_camera, default.R_body_camera)
        and np.array_equal(rig.R_body_imu, default.R_body_imu)
        and rig.time_offset_s == default.time_offset_s
    ):
        return mount
    if mount != MountOptions():
        raise UsageError(
            f"--mount/--imu-axes/--imu-time-offset: the calibration file {camera.calibration} carries a "
            "mount already; give the mount in one place"
        )
    try:
        return MountOptions(
            mount=_numbers(rig.R_body_camera),
            imu_axes=_numbers(rig.R_body_imu),
            imu_time_offset_s=rig.time_offset_s,
        )
    except ValidationError as exc:
        problem = condense_validation_error(exc, flag_of)
        raise UsageError(f"--calibration {camera.calibration}: {problem}") from None


def _numbers(R: FloatArray) -> str:
    """A rotation as the 9 comma-separated numbers (row-major, exact repr) :func:`mount_rotation` reads."""
    return ",".join(repr(float(v)) for v in np.asarray(R, dtype=np.float64).ravel())


def add_rig_options(parser: argparse.ArgumentParser, default_camera: CameraModel | None) -> None:
    """The rig option group: the camera's (:func:`~services.runtime.camera_options.add_camera_options`,
    ``default_camera`` when none is given) and the mount's (:func:`add_mount_options`)."""
    add_camera_options(parser, default_camera)
    add_mount_options(parser)


def rig_options_from_args(args: argparse.Namespace) -> tuple[CameraOptions, MountOptions]:
    """The rig option group's values: the camera's, and the mount as given or as its ``--calibration`` file
    carries it (:func:`mount_of_calibration`; a bad value or a mount given twice: one UsageError line)."""
    camera = camera_options_from_args(args)
    return camera, mount_of_calibration(camera, mount_options_from_args(args))
