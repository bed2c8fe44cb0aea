"""One camera option group for every command that needs a camera (master, estimator, localizer).

``--calibration FILE`` (any rig file :func:`common.datasets.rig_files.load_rig` reads: OpenCV YAML, ROS
``camera_info`` YAML, the capataz rig YAML, EuRoC ``sensor.yaml``, Kalibr ``camchain.yaml``; a mount it
carries reaches the services through :func:`services.runtime.mount_options.mount_of_calibration`), or explicit
intrinsics (``--fx``, ``--fy``, ``--cx``, ``--cy`` with ``--distortion`` and ``--distortion-coeffs``), or a
pinhole of ``--resolution`` and ``--hfov``; nothing given = the command's default camera (the simulated one it
is run against; the master's is none: an undistorted camera centred on the frame). :class:`CameraOptions`
holds the values (a path is a value); :func:`load_camera` reads the file, at the service's boundary, and is
the one place a camera model is made from options. A fisheye file with all-zero coefficients is the ideal
equidistant lens (r = f theta), not a pinhole; it is said in one log line."""

from __future__ import annotations

import argparse
import logging
import math
from enum import StrEnum
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from common.camera import CameraModel, Distortion, DistortionModel
from common.datasets.rig_files import load_rig
from common.errors import InputError
from services.runtime.cli import add_enum_argument, parse_size
from services.runtime.usage import UsageError, condense_validation_error

logger = logging.getLogger(__name__)


class LensModel(StrEnum):
    NONE = "none"
    RADTAN = "radtan"  # OpenCV k1 k2 p1 p2 k3 (ROS plumb_bob)
    FISHEYE = "fisheye"  # OpenCV fisheye k1 k2 k3 k4 (ROS equidistant)


class CameraOptions(BaseModel):
    """What a command is told about its camera: a calibration file, or explicit intrinsics (``fy`` defaults
    to ``fx``, ``cx``/``cy`` to the frame centre) with a distortion model, or a pinhole of a size and a
    horizontal field of view; all empty = the command's default camera."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    calibration: Path | None = None
    width: int | None = Field(default=None, gt=0)
    height: int | None = Field(default=None, gt=0)
    hfov_deg: float | None = Field(default=None, gt=0.0, lt=180.0)
    fx: float | None = Field(default=None, gt=0.0)
    fy: float | None = Field(default=None, gt=0.0)
    cx: float | None = None
    cy: float | None = None
    distortion: LensModel = LensModel.NONE
    coeffs: tuple[float, ...] = ()

    @model_validator(mode="after")
    def _consistent(self) -> CameraOptions:
        explicit = any(v is not None for v in (self.fx, self.fy, self.cx, self.cy)) or bool(self.coeffs)
        if self.calibration is not None and (explicit or self.hfov_deg is not None):
            raise ValueError("give a calibration file or explicit intrinsics or a field of view, not two")
        if explicit and self.fx is None:
            raise ValueError("explicit intrinsics need at least fx")
        if explicit and self.hfov_deg is not None:
            raise ValueError("give explicit intrinsics or a field of view, not both")
        if self.distortion is not LensModel.NONE and self.calibration is None and self.fx is None:
            raise ValueError("a distortion model needs intrinsics (fx or a calibration file)")
        if self.fx is not None:
            Distortion(DistortionModel[self.distortion.name], self.coeffs)  # the coefficient count
        return self

    @property
    def given(self) -> bool:
        """True when anything is set (else the command's default camera)."""
        return self != CameraOptions()


def load_camera(
    options: CameraOptions, default: CameraModel | None, frame_size: tuple[int, int] | None = None
) -> CameraModel | None:
    """The camera the options describe (reading the calibration file); ``default`` when nothing is set.

    The size of explicit intrinsics or of a field of view is ``--resolution``, else ``frame_size`` (the
    frames', when known), else the default camera's (else the built-in 752x480)."""
    if options.calibration is not None:
        camera = load_rig(options.calibration).camera
        if camera.distortion.model is DistortionModel.FISHEYE and not any(camera.distortion.coeffs):
            logger.warning(
                "%s: fisheye with all-zero coefficients: the ideal equidistant lens (r = f theta), not a "
                "pinhole",
                options.calibration,
            )
        return camera
    if options.fx is None and options.hfov_deg is None and options.width is None:
        return default
    base = default if default is not None else CameraModel.default()
    if options.width is not None and options.height is not None:
        width, height = options.width, options.height
    else:
        width, height = frame_size if frame_size is not None else (base.width, base.height)
    if options.fx is None:
        hfov = options.hfov_deg if options.hfov_deg is not None else _hfov_deg(base)
        return CameraModel.from_hfov(width, height, hfov)
    return CameraModel(
        width=width,
        height=height,
        fx=options.fx,
        fy=options.fy if options.fy is not None else options.fx,
        cx=options.cx if options.cx is not None else (width - 1) / 2.0,
        cy=options.cy if options.cy is not None else (height - 1) / 2.0,
        distortion=Distortion(DistortionModel[options.distortion.name], options.coeffs),
    )


def _hfov_deg(camera: CameraModel) -> float:
    return round(math.degrees(camera.hfov_rad), 9)


def describe_camera(camera: CameraModel | None) -> str:
    """``752x480, hfov 90 deg`` (the default's words in the option group's title)."""
    if camera is None:
        return "none: an undistorted camera centred on the frame"
    return f"{camera.width}x{camera.height}, hfov {_hfov_deg(camera):g} deg"


def add_camera_options(parser: Any, default: CameraModel | None) -> None:
    """The camera option group (the same for every command; ``default`` is what nothing given means)."""
    group = parser.add_argument_group(
        f"camera (one of: a calibration file, explicit intrinsics, a resolution and FOV; default "
        f"{describe_camera(default)})"
    )
    group.add_argument(
        "--calibration", type=Path, help="OpenCV YAML or ROS camera_info YAML calibration file"
    )
    group.add_argument("--resolution", help="camera WIDTHxHEIGHT (default: the frames' or the default's)")
    group.add_argument("--hfov", dest="hfov_deg", type=float, help="horizontal field of view (deg)")
    group.add_argument("--fx", type=float, help="focal length x (px); --fy defaults to it")
    group.add_argument("--fy", type=float, help="focal length y (px); default --fx")
    group.add_argument("--cx", type=float, help="principal point x (px); default the frame centre")
    group.add_argument("--cy", type=float, help="principal point y (px); default the frame centre")
    add_enum_argument(group, "--distortion", LensModel, LensModel.NONE, help="lens distortion model")
    group.add_argument(
        "--distortion-coeffs",
        help="comma-separated coefficients: radtan k1,k2,p1,p2,k3; fisheye k1,k2,k3,k4",
    )


_OPTION_OF = {
    "hfov_deg": "--hfov",
    "width": "--resolution",
    "height": "--resolution",
    "coeffs": "--distortion-coeffs",
}


def _option_of(field: str) -> str:
    if field not in CameraOptions.model_fields:
        return "camera"
    return _OPTION_OF.get(field, "--" + field.replace("_", "-"))


def camera_options_from_args(args: argparse.Namespace) -> CameraOptions:
    """The group's values, validated (one :class:`UsageError` line, exit 2, when inconsistent)."""
    try:
        coeffs = tuple(float(v) for v in (args.distortion_coeffs or "").split(",") if v.strip())
    except ValueError:
        raise UsageError(
            f"--distortion-coeffs must be comma-separated numbers, got {args.distortion_coeffs!r}"
        ) from None
    width = height = None
    if args.resolution is not None:
        width, height = parse_size(args.resolution, "--resolution", "752x480")
    try:
        return CameraOptions(
            calibration=args.calibration,
            width=width,
            height=height,
            hfov_deg=args.hfov_deg,
            fx=args.fx,
            fy=args.fy,
            cx=args.cx,
            cy=args.cy,
            distortion=LensModel(args.distortion),
            coeffs=coeffs,
        )
    except ValidationError as exc:
        text = condense_validation_error(exc, _option_of)
        raise UsageError(text) from None
    except InputError as exc:
        raise UsageError(f"camera options: {exc}") from None


def camera_from_args(args: argparse.Namespace, default: CameraModel | None) -> CameraModel | None:
    """The group's camera, its file read now: a bad one stops the command at start with one line."""
    return load_camera(camera_options_from_args(args), default)
