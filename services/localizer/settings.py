"""Settings of ``capataz localizer``: the model file, the camera (calibration file or resolution + FOV), the
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

from common.camera import CameraModel
from common.datasets.calibration import load_calibration
from common.datasets.models import load_model
from common.errors import CapatazError
from common.geometry import CameraMount
from common.localization.model import SceneModel
from common.localization.office import default_scene
from common.localization.particle_filter import ParticleFilterSettings
from common.localization.pose import CameraPose, parse_pose_numbers
from common.localization.scoring import ScoringMethod, ScoringSettings
from common.localization.tracker_state import TrackerSettings
from common.sim.office_run import OFFICE_HEIGHT_PX, OFFICE_HFOV_DEG, OFFICE_WIDTH_PX
from common.sim.scene import default_flight
from services.runtime.cli import add_enum_argument, add_transport_arguments, parse_size
from services.runtime.fields import settings_from

#: the body's camera mounts, plus "camera": the published pose is the camera's own (no body)
_MOUNTS = {**{m.value: m.R_body_camera for m in CameraMount}, "camera": np.eye(3)}


class FilterKind(enum.Enum):
    """Which estimator the localizer runs: ``particle`` = paper B's particle filter driven by the VO
    odometry, ``tracker`` = the model tracker (no odometry needed), ``auto`` = the particle filter when
    ``use_vo`` supplies odometry, the tracker otherwise."""

    AUTO = "auto"
    PARTICLE = "particle"
    TRACKER = "tracker"


class LocalizerSettings(BaseModel):
    """What the localizer needs besides the transport."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    uav: str = "uav0"
    #: model file (.json, .obj, .cao; see common.datasets.models); None = the built-in office
    model: Path | None = None
    #: factor from the OBJ file's units to metres
    model_scale: float = Field(default=1.0, gt=0.0)
    #: camera calibration (OpenCV YAML or ROS camera_info YAML); None = width x height with hfov_deg
    calibration: Path | None = None
    width: int = Field(default=OFFICE_WIDTH_PX, gt=0)
    height: int = Field(default=OFFICE_HEIGHT_PX, gt=0)
    hfov_deg: float = Field(default=OFFICE_HFOV_DEG, gt=0.0, lt=180.0)
    #: how the camera sits on the body that pose/pf reports ("camera": the camera itself)
    camera_mount: Literal["forward", "down", "camera"] = "forward"
    particles: int = Field(default=200, ge=2)
    scoring: ScoringMethod = ScoringMethod.NEAREST_EDGE_DT
    seed: int = 0
    #: camera-from-world, 6 numbers (rvec, tvec) or 16 (4x4 row-major); overrides initial_state
    initial_pose: tuple[float, ...] | None = None
    #: initial body state (x, y, z, roll, pitch, yaw) in m and rad; None (and no initial_pose) = the
    #: simulated office flight's first pose
    initial_state: tuple[float, float, float, float, float, float] | None = None
    #: start / recovery spread (m per axis; None = 0.1 x the viewing distance) and angle spread (deg)
    position_spread_m: float | None = Field(default=None, gt=0.0)
    angle_spread_deg: float = Field(default=8.0, gt=0.0, le=90.0)
    #: process noise overrides: unmodelled velocity (m/s) and rate (deg/s); None = derived in pixels per
    #: frame from the model, the camera and the stream (common.localization.process_noise)
    velocity_noise_m_s: float | None = Field(default=None, gt=0.0)
    angular_noise_deg_s: float | None = Field(default=None, gt=0.0)
    layers: int = Field(default=2, ge=1, le=10)
    use_vo: bool = False
    #: with use_vo: a VO step faster than this (m/s) is a discontinuity (the odometry restarted, the
    #: camera looped), after which the localizer starts again around the new VO pose
    vo_jump_m_s: float = Field(default=10.0, gt=0.0)
    #: tracker: the gyro on capataz/uav/{uav}/imu measures the motion model's angular rate
    use_imu: bool = False
    filter: FilterKind = FilterKind.AUTO

    @field_validator("initial_pose")
    @classmethod
    def _pose_length(cls, value: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if value is not None:
            parse_pose_numbers(value)  # raises InputError (a ValueError) with the reason
        return value

    @property
    def R_body_camera(self) -> np.ndarray:
        return np.asarray(_MOUNTS[self.camera_mount], dtype=np.float64)

    def camera(self) -> CameraModel:
        if self.calibration is not None:
            return load_calibration(self.calibration)
        return CameraModel.from_hfov(self.width, self.height, self.hfov_deg)

    def load_scene(self) -> SceneModel:
        if self.model is None:
            return default_scene()
        return load_model(self.model, self.model_scale)

    def start_pose(self) -> CameraPose:
        """The initial camera pose (see the field docs)."""
        if self.initial_pose is not None:
            return parse_pose_numbers(self.initial_pose)
        state = default_flight(n_frames=2).states[0] if self.initial_state is None else self.initial_state
        return CameraPose.from_body_state(state, self.R_body_camera)

    @property
    def anchor_on_vo(self) -> bool:
        """With ``use_vo`` and no initial pose given, the VO poses (in the model's world frame) place the
        filter: it starts around the first one and again after a VO discontinuity."""
        return self.use_vo and self.initial_pose is None and self.initial_state is None

    def resolved_filter(self) -> FilterKind:
        """``filter`` with ``auto`` resolved: the particle filter with VO odometry, the tracker without."""
        if self.filter is not FilterKind.AUTO:
            return self.filter
        return FilterKind.PARTICLE if self.use_vo else FilterKind.TRACKER

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
            angle_spread_rad=float(np.radians(self.angle_spread_deg)),
            velocity_noise_m_s=self.velocity_noise_m_s,
            angular_noise_rad_s=(
                None if self.angular_noise_deg_s is None else float(np.radians(self.angular_noise_deg_s))
            ),
        )


def register_arguments(parser: Any) -> None:
    add_transport_arguments(parser, node_default="localizer")
    parser.add_argument("--uav", default="uav0", help="UAV stream id (default uav0)")
    parser.add_argument(
        "--model", "--scene", dest="model", type=Path, help="model file .json/.obj/.cao (default: the office)"
    )
    parser.add_argument("--model-scale", type=float, default=1.0, help="OBJ units to metres (e.g. 0.001)")
    parser.add_argument(
        "--calibration", type=Path, help="camera calibration (OpenCV or ROS camera_info YAML)"
    )
    parser.add_argument(
        "--resolution",
        default=f"{OFFICE_WIDTH_PX}x{OFFICE_HEIGHT_PX}",
        help="camera WIDTHxHEIGHT (no file)",
    )
    parser.add_argument(
        "--hfov", dest="hfov_deg", type=float, default=OFFICE_HFOV_DEG, help="horizontal FOV (deg; no file)"
    )
    parser.add_argument(
        "--mount", dest="camera_mount", choices=sorted(_MOUNTS), default="forward", help="camera on the body"
    )
    parser.add_argument("--particles", type=int, default=200, help="number of particles (default 200)")
    add_enum_argument(
        parser, "--scoring", ScoringMethod, ScoringMethod.NEAREST_EDGE_DT,
        help="paper B's image-closeness measure (nearest_edge_dt: nearest edge through a distance transform)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of the filter's random numbers")
    parser.add_argument(
        "--initial-pose",
        type=float,
        nargs="+",
        metavar="V",
        help="camera-from-world: RX RY RZ TX TY TZ (OpenCV rvec rad, tvec m) or the 4x4 matrix (16 numbers)",
    )
    parser.add_argument(
        "--initial-state",
        type=float,
        nargs=6,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="initial body pose (m, rad) instead; default: the simulated office flight's start",
    )
    parser.add_argument(
        "--position-spread",
        dest="position_spread_m",
        type=float,
        help="tracker: start/recovery spread, m (default 0.1 x distance)",
    )
    parser.add_argument(
        "--angle-spread",
        dest="angle_spread_deg",
        type=float,
        default=8.0,
        help="tracker: start/recovery spread, deg (default 8)",
    )
    parser.add_argument(
        "--velocity-noise",
        dest="velocity_noise_m_s",
        type=float,
        help="tracker: process noise override, m/s (default: from pixels per frame, see process_noise)",
    )
    parser.add_argument(
        "--angular-noise",
        dest="angular_noise_deg_s",
        type=float,
        help="tracker: process noise override, deg/s (default: from pixels per frame, see process_noise)",
    )
    parser.add_argument(
        "--layers", type=int, default=2, help="tracker: annealing layers per frame (default 2)"
    )
    parser.add_argument(
        "--use-vo",
        action="store_true",
        help="drive the prediction by pose/vo; without --initial-pose/--initial-state the VO frame is the "
        "model's world frame: start around the first VO pose, start again after a VO jump",
    )
    parser.add_argument(
        "--vo-jump",
        dest="vo_jump_m_s",
        type=float,
        default=10.0,
        help="with --use-vo: a VO step faster than this (m/s) is a discontinuity (default 10)",
    )
    parser.add_argument(
        "--use-imu",
        action="store_true",
        help="tracker: the gyro on capataz/uav/{uav}/imu measures the motion model's angular rate",
    )
    add_enum_argument(
        parser, "--filter", FilterKind, FilterKind.AUTO,
        help="particle: paper B's particle filter (predicted by pose/vo); tracker: the model tracker (no "
        "odometry needed); auto (default): particle with --use-vo, tracker without",
    )  # fmt: skip


def settings_from_args(args: argparse.Namespace) -> LocalizerSettings:
    width, height = parse_size(args.resolution, "--resolution", "320x240")
    try:
        # every option's dest is its field's name (pydantic parses the enum values and the number lists)
        return settings_from(LocalizerSettings, args, width=width, height=height)
    except ValueError as exc:
        raise CapatazError(f"invalid localizer settings: {exc}") from None
