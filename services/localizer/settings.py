"""Settings of ``capataz localizer``: the model file, the camera (the shared camera option group), the
initial pose, which estimator (``--filter``: paper B's particle filter or the model tracker), the tracker's
knobs, and the command line that fills them.

``--initial-pose`` is camera-from-world (:func:`common.localization.pose.parse_pose_numbers`): 6 numbers =
OpenCV ``rvec`` (rad) then ``tvec`` (m), as ``cv2.solvePnP`` returns them; 16 numbers = the 4x4 matrix row by
row. ``--initial-state X Y Z ROLL PITCH YAW`` gives the body pose instead (the camera on its ``--mount``).
"""

from __future__ import annotations

import argparse
import enum
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from common.geometry import CameraMount
from common.localization.office import OFFICE_START_STATE, office_camera
from common.localization.particle_filter import ParticleFilterSettings
from common.localization.pose import CameraPose, parse_pose_numbers
from common.localization.scoring import ParticleSettings, ScoringMethod, ScoringSettings
from common.localization.tracker_state import TrackerSettings
from services.runtime.camera_options import CameraOptions, add_camera_options, camera_options_from_args
from services.runtime.cli import add_transport_arguments
from services.runtime.fields import settings_from
from services.runtime.options import DEGREES, add_options, from_core

#: the body's camera mounts, plus "camera": the published pose is the camera's own (no body)
_MOUNTS = {**{m.value: m.R_body_camera for m in CameraMount}, "camera": np.eye(3)}


class LocalizerKind(enum.Enum):
    """Which estimator the localizer runs: ``particle`` = paper B's particle filter driven by the VO
    odometry, ``tracker`` = the model tracker (no odometry needed), ``auto`` = the particle filter when
    ``use_vo`` supplies odometry, the tracker otherwise."""

    AUTO = "auto"
    PARTICLE = "particle"
    TRACKER = "tracker"


class LocalizerSettings(BaseModel):
    """What the localizer needs besides the transport: its camera's and filters' defaults, bounds and help
    texts are the cores' (:func:`~services.runtime.options.from_core`); files are read by
    :mod:`services.localizer.loading`, not here."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = Field(default="uav0", description="UAV stream id")
    #: model file (.json, .obj, .cao; see common.datasets.models); None = the built-in office
    model: Path | None = Field(default=None, description="model file .json/.obj/.cao (default: the office)")
    model_scale: float = Field(default=1.0, gt=0.0, description="factor from the OBJ file's units to metres")
    #: the camera option group's values (nothing given: the simulated office camera)
    camera: CameraOptions = CameraOptions()
    camera_mount: Literal["forward", "down", "camera"] = Field(
        default="forward", description="how the camera sits on the body that pose/pf reports (camera: itself)"
    )
    particles: int = from_core(ParticleSettings, "n_particles")
    scoring: ScoringMethod = from_core(ScoringSettings, "method")
    seed: int = Field(default=0, description="seed of the filter's random numbers")
    initial_pose: tuple[float, ...] | None = Field(
        default=None,
        description="camera-from-world: RX RY RZ TX TY TZ (OpenCV rvec rad, tvec m) or the 4x4 matrix (16 "
        "numbers); overrides --initial-state",
    )
    initial_state: tuple[float, float, float, float, float, float] | None = Field(
        default=None,
        description="initial body pose (m, rad) instead; default: the simulated office flight's start",
    )
    position_spread_m: float | None = from_core(TrackerSettings, "position_spread_m")
    angle_spread_deg: float = from_core(TrackerSettings, "angle_spread_rad", unit=DEGREES)
    velocity_noise_m_s: float | None = from_core(TrackerSettings, "velocity_noise_m_s")
    angular_noise_deg_s: float | None = from_core(TrackerSettings, "angular_noise_rad_s", unit=DEGREES)
    layers: int = from_core(TrackerSettings, "layers")
    use_vo: bool = Field(
        default=False,
        description="drive the prediction by pose/vo; without --initial-pose/--initial-state the VO frame is "
        "the model's world frame: start around the first VO pose, start again after a VO jump",
    )
    vo_jump_m_s: float = Field(
        default=10.0, gt=0.0, description="with --use-vo: a VO step faster than this (m/s) is a discontinuity"
    )
    use_imu: bool = Field(
        default=False, description="tracker: the gyro on capataz/uav/{uav}/imu measures the angular rate"
    )
    filter: LocalizerKind = Field(
        default=LocalizerKind.AUTO,
        description="particle: paper B's particle filter (predicted by pose/vo); tracker: the model tracker "
        "(no odometry needed); auto: particle with --use-vo, tracker without",
    )

    @field_validator("initial_pose")
    @classmethod
    def _pose_length(cls, value: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if value is not None:
            parse_pose_numbers(value)  # raises InputError (a ValueError) with the reason
        return value

    @property
    def R_body_camera(self) -> np.ndarray:
        return np.asarray(_MOUNTS[self.camera_mount], dtype=np.float64)

    def start_pose(self) -> CameraPose:
        """The initial camera pose (see the field docs)."""
        if self.initial_pose is not None:
            return parse_pose_numbers(self.initial_pose)
        state = OFFICE_START_STATE if self.initial_state is None else self.initial_state
        return CameraPose.from_body_state(state, self.R_body_camera)

    @property
    def anchor_on_vo(self) -> bool:
        """With ``use_vo`` and no initial pose given, the VO poses (in the model's world frame) place the
        filter: it starts around the first one and again after a VO discontinuity."""
        return self.use_vo and self.initial_pose is None and self.initial_state is None

    def resolved_filter(self) -> LocalizerKind:
        """``filter`` with ``auto`` resolved: the particle filter with VO odometry, the tracker without."""
        if self.filter is not LocalizerKind.AUTO:
            return self.filter
        return LocalizerKind.PARTICLE if self.use_vo else LocalizerKind.TRACKER

    def particle_filter_settings(self) -> ParticleFilterSettings:
        """Paper B's filter: ``particles``, ``scoring`` and the mount; its own noise and start spreads."""
        return ParticleFilterSettings(
            n_particles=self.particles,
            scoring=ScoringSettings(method=self.scoring),
            R_body_camera=self.R_body_camera.copy(),
        )

    def tracker_settings(self) -> TrackerSettings:
        return TrackerSettings(
            n_particles=self.particles,
            layers=self.layers,
            scoring=ScoringSettings(method=self.scoring),
            position_spread_m=self.position_spread_m,
            angle_spread_rad=DEGREES.core(self.angle_spread_deg),
            velocity_noise_m_s=self.velocity_noise_m_s,
            angular_noise_rad_s=(
                None if self.angular_noise_deg_s is None else DEGREES.core(self.angular_noise_deg_s)
            ),
        )


#: the options in the order of ``--help``; each one's default, bound and help text is its field's
_OPTIONS = (
    "uav", "model", "model_scale", "camera_mount", "particles", "scoring", "seed", "initial_pose",
    "initial_state", "position_spread_m", "angle_spread_deg", "velocity_noise_m_s", "angular_noise_deg_s",
    "layers", "use_vo", "vo_jump_m_s", "use_imu", "filter",
)  # fmt: skip


def register_arguments(parser: Any) -> None:
    add_transport_arguments(parser, node_default="localizer")
    add_camera_options(parser, office_camera())
    add_options(
        parser,
        LocalizerSettings,
        _OPTIONS,
        flags={"model": ("--model", "--scene"), "camera_mount": "--mount"},
        extra={
            "initial_pose": {"type": float, "nargs": "+", "metavar": "V"},
            "initial_state": {"type": float, "nargs": 6, "metavar": ("X", "Y", "Z", "ROLL", "PITCH", "YAW")},
        },
    )


def settings_from_args(args: argparse.Namespace) -> LocalizerSettings:
    """The settings of the command line (a value out of its bound: a ValidationError, one line, exit 2)."""
    # every option's dest is its field's name (pydantic parses the enum values and the number lists)
    return settings_from(LocalizerSettings, args, camera=camera_options_from_args(args))
