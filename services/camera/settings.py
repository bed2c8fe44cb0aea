"""The camera's settings (``capataz camera``'s options) and the simulated flights it can replay."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from common.members import Role
from common.wire.frame_codec import DEFAULT_JPEG_QUALITY, FrameEncoding


class FlightName(StrEnum):
    """The simulated flights the camera can replay."""

    #: paper A's hover over the ground (752x480)
    HOVER = "hover"
    #: paper C's turns over the ground
    TURNS = "turns"
    #: the localizer's default flight through the built-in office (320x240, forward camera)
    OFFICE = "office"
    #: field scenarios (``common.sim.field.FIELD_SCENARIOS``, 320x240 over the ground): one effect each
    CHECKERBOARD = "checkerboard"
    TILES = "tiles"
    WIDE_ANGLE = "wide_angle"
    LOW_ALTITUDE = "low_altitude"
    BLUR_EXPOSURE = "blur_exposure"
    FAST_YAW = "fast_yaw"
    #: all field effects together
    FIELD = "field"
    #: the field flight on a rig: camera tilted and turned, IMU in other axes with a clock offset
    MOUNTED_RIG = "mounted_rig"
    #: the field flight with bursty stamps and dropped frames (the yaw bench runs it without the IMU)
    BURSTY_NO_IMU = "bursty_no_imu"
    #: all of them
    FIELD_NUISANCES = "field_nuisances"


class CameraSettings(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    uavs: tuple[str, ...] = ("uav0",)
    flight: FlightName = FlightName.HOVER
    frames: int = Field(default=2041, ge=2)
    seed: int = 0
    fps: float = Field(default=20.0, ge=0.0)
    loop: bool = False
    #: a recorded input instead of a simulation (at most one; see services/camera/sources.py)
    images: Path | None = None
    #: per-frame stamps of ``images``: ``index,stamp`` CSV or EuRoC's ``data.csv``
    stamps: Path | None = None
    start: int = Field(default=0, ge=0)
    stop: int | None = Field(default=None, ge=0)
    step: int = Field(default=1, ge=1)
    calibration: Path | None = None
    bag: Path | None = None
    image_topic: str | None = None
    imu_topic: str | None = None
    range_topic: str | None = None
    camera_info_topic: str | None = None
    euroc: Path | None = None
    mcap: Path | None = None
    #: a recording's replay speed (1 = recorded rate; 0 = as fast as consumed; ``fps = 0`` also unpaces)
    rate: float = Field(default=1.0, ge=0.0)
    #: image size; None = the flight's own camera (752x480 over the ground, 320x240 in the office); another
    #: size keeps the flight's field of view (a field scenario's own lens, else a 90 deg pinhole)
    width: int | None = None
    height: int | None = None
    sensors: bool = True
    in_flight: int = Field(default=0, ge=0)
    #: read every image of ``images`` before publishing
    preload: bool = False
    #: wait this long for a member of ``wait_for`` (and its frame subscription) before the first frame
    #: (0 = do not wait)
    wait_master_s: float = Field(default=10.0, ge=0.0)
    #: whose frame subscription the camera waits for: the master (yaw), or the estimator or the localizer
    #: when the camera feeds one without a master (a recording otherwise plays to nobody while it starts)
    wait_for: Role = Role.MASTER
    #: give up waiting for a yaw after this long (flow control only)
    yaw_timeout_s: float = Field(default=5.0, gt=0.0)
    frame_codec: FrameEncoding = Field(
        default="mono8",
        description="how frames travel to the master: mono8 raw, png or zstd (lossless: bit-identical), "
        "jpeg (lossy, at --jpeg-quality); receivers decode any of them",
    )
    jpeg_quality: int = Field(
        default=DEFAULT_JPEG_QUALITY, ge=1, le=100, description="with --frame-codec jpeg: its quality, 1-100"
    )
