"""The master's yaw options: the camera's intrinsics and lens distortion, from a calibration file (OpenCV
YAML or ROS ``camera_info`` YAML) or explicit values, on the command line and in the settings; the gyro
prior and the physical yaw-rate limit on the command line.

The yaw core undistorts the correspondences (patch centres and shifted centres) before its fit, so a
wide-angle lens measures the same rotation as a pinhole. A calibration made at another resolution of the
same aspect ratio is scaled to the frames; another aspect ratio is refused.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.calibration import load_calibration
from common.errors import InputError
from common.yaw.settings import YawSettings
from services.runtime.cli import add_enum_argument


class LensModel(StrEnum):
    NONE = "none"
    RADTAN = "radtan"  # OpenCV k1 k2 p1 p2 k3 (ROS plumb_bob)
    FISHEYE = "fisheye"  # OpenCV fisheye k1 k2 k3 k4 (ROS equidistant)


class LensSettings(BaseModel):
    """Either ``calibration`` (a file) or explicit ``fx`` (``fy`` defaults to ``fx``, ``cx``/``cy`` to the
    frame centre) with a distortion model and its coefficients; all empty = an undistorted camera centred
    on the frame (the yaw then needs no intrinsics)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    calibration: Path | None = None
    fx: float | None = Field(default=None, gt=0.0)
    fy: float | None = Field(default=None, gt=0.0)
    cx: float | None = None
    cy: float | None = None
    distortion: LensModel = LensModel.NONE
    coeffs: tuple[float, ...] = ()

    @model_validator(mode="after")
    def _consistent(self) -> LensSettings:
        explicit = any(v is not None for v in (self.fx, self.fy, self.cx, self.cy)) or self.coeffs
        if self.calibration is not None and explicit:
            raise ValueError("give a calibration file or explicit intrinsics, not both")
        if explicit and self.fx is None:
            raise ValueError("explicit intrinsics need at least fx")
        if self.distortion is not LensModel.NONE and self.calibration is None and self.fx is None:
            raise ValueError("a distortion model needs intrinsics (fx or a calibration file)")
        return self

    def camera(self, width: int | None = None, height: int | None = None) -> CameraModel | None:
        """The camera model (None when nothing is set); explicit intrinsics need the frame size."""
        if self.calibration is not None:
            return load_calibration(self.calibration)
        if self.fx is None:
            return None
        if width is None or height is None:
            raise InputError("explicit intrinsics need the frame size")
        distortion = Distortion(DistortionModel[self.distortion.name], tuple(self.coeffs))
        return CameraModel(
            width=width,
            height=height,
            fx=self.fx,
            fy=self.fy if self.fy is not None else self.fx,
            cx=self.cx if self.cx is not None else (width - 1) / 2.0,
            cy=self.cy if self.cy is not None else (height - 1) / 2.0,
            distortion=distortion,
        )


class YawPriorSettings(BaseModel):
    """What the master's central stage adds to the shared yaw settings: the lens, the gyro prior, limits."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    lens: LensSettings = LensSettings()
    #: use the stream's IMU (``capataz/uav/{uav}/imu``) as the yaw's prior and bridge
    gyro_prior: bool = True
    #: how long a frame may wait for IMU samples reaching its stamp (s)
    gyro_wait_s: float = Field(default=0.05, ge=0.0, le=1.0)
    #: physical yaw-rate limit (deg/s): deltas implying more are refused
    max_yaw_rate_deg_s: float = Field(default=300.0, gt=0.0)

    def tracker_settings(self, base: YawSettings, width: int, height: int) -> YawSettings:
        """The central stage's settings for frames of ``width`` x ``height``."""
        return replace(
            base, camera=self.lens.camera(width, height), max_yaw_rate_deg_s=self.max_yaw_rate_deg_s
        )


def add_yaw_prior_arguments(parser: argparse.ArgumentParser) -> None:
    """The master's lens options and its yaw prior's (gyro, physical rate limit)."""
    parser.add_argument(
        "--no-gyro-prior",
        action="store_true",
        help="ignore the IMU: hold the recent yaw rate over untrusted pairs",
    )
    parser.add_argument(
        "--max-yaw-rate", type=float, default=300.0, help="physical yaw-rate limit in deg/s (default 300)"
    )
    group = parser.add_argument_group("camera lens (yaw undistorts its correspondences)")
    group.add_argument(
        "--calibration", type=Path, help="OpenCV YAML or ROS camera_info YAML calibration file"
    )
    group.add_argument("--fx", type=float, help="focal length x (px); --fy defaults to it")
    group.add_argument("--fy", type=float, help="focal length y (px); default --fx")
    group.add_argument("--cx", type=float, help="principal point x (px); default the frame centre")
    group.add_argument("--cy", type=float, help="principal point y (px); default the frame centre")
    add_enum_argument(group, "--distortion", LensModel, LensModel.NONE, help="lens distortion model")
    group.add_argument(
        "--distortion-coeffs",
        default="",
        help="comma-separated coefficients: radtan k1,k2,p1,p2,k3; fisheye k1,k2,k3,k4",
    )


def yaw_prior_settings_from_args(args: argparse.Namespace) -> YawPriorSettings:
    """Lens, gyro prior and rate limit from the command line (one InputError line when inconsistent)."""
    if not (args.max_yaw_rate > 0.0):
        raise InputError(f"--max-yaw-rate must be positive, got {args.max_yaw_rate}")
    return YawPriorSettings(
        lens=lens_settings_from_args(args),
        gyro_prior=not args.no_gyro_prior,
        max_yaw_rate_deg_s=args.max_yaw_rate,
    )


def lens_settings_from_args(args: argparse.Namespace) -> LensSettings:
    """Validated lens settings; a bad file or inconsistent options raise one InputError line."""
    try:
        coeffs = tuple(float(v) for v in args.distortion_coeffs.split(",") if v.strip())
    except ValueError:
        raise InputError(
            f"--distortion-coeffs must be comma-separated numbers, got {args.distortion_coeffs!r}"
        ) from None
    try:
        lens = LensSettings(
            calibration=args.calibration,
            fx=args.fx,
            fy=args.fy,
            cx=args.cx,
            cy=args.cy,
            distortion=LensModel(args.distortion),
            coeffs=coeffs,
        )
    except ValueError as exc:  # pydantic's ValidationError is a ValueError
        raise InputError(f"lens options: {str(exc).splitlines()[-1].strip()}") from None
    if lens.calibration is not None:
        lens.camera()  # read it now: a bad file stops the service at start with one line
    else:
        Distortion(DistortionModel[lens.distortion.name], lens.coeffs)  # the coefficient count
    return lens
