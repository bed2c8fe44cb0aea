"""The estimator's inputs: one sensor enum, one value type per sensor, their checks and one sensor order."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from common.errors import InputError
from common.images import check_grey_image
from common.types import FloatArray, U8Array


class Sensor(enum.Enum):
    """Input streams of the estimator."""

    IMU = "imu"
    RANGE = "range"
    CAMERA = "camera"
    YAW = "yaw"


#: Application order of samples with equal stamps: the range first (it initialises the altitude), then the
#: IMU, an external yaw, the camera. The one order used by the estimator and the replays.
SENSOR_ORDER: dict[Sensor, int] = {Sensor.RANGE: 0, Sensor.IMU: 1, Sensor.YAW: 2, Sensor.CAMERA: 3}


@dataclass(frozen=True)
class ImuMeasurement:
    """Gyro (rad/s, body) and specific force (m/s^2, body) at ``stamp_s``."""

    stamp_s: float
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray


@dataclass(frozen=True)
class RangeMeasurement:
    """Rangefinder reading along the body's -z axis."""

    stamp_s: float
    range_m: float


@dataclass(frozen=True)
class YawMeasurement:
    """An external yaw (e.g. from the yaw cluster), any unwrapping, and the variance its source published
    with it (rad^2; 0 where the source gave none)."""

    stamp_s: float
    yaw_rad: float
    variance_rad2: float = 0.0


@dataclass(frozen=True)
class FrameMeasurement:
    """A grey camera frame."""

    stamp_s: float
    image: U8Array


Measurement = ImuMeasurement | RangeMeasurement | YawMeasurement | FrameMeasurement


def check_imu(stamp_s: float, gyro_rad_s: npt.ArrayLike, accel_m_s2: npt.ArrayLike) -> ImuMeasurement:
    """Validated IMU sample (finite stamp, two finite 3-vectors) or InputError."""
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    accel = np.asarray(accel_m_s2, dtype=np.float64)
    if gyro.shape != (3,) or accel.shape != (3,):
        raise InputError(f"gyro and accel must have shape (3,), got {gyro.shape} and {accel.shape}")
    if not (math.isfinite(stamp_s) and np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel))):
        raise InputError("IMU sample has a non-finite stamp, gyro or accel value")
    return ImuMeasurement(stamp_s=float(stamp_s), gyro_rad_s=gyro, accel_m_s2=accel)


def check_range(stamp_s: float, range_m: float) -> RangeMeasurement:
    """Validated range sample (finite stamp, finite positive range) or InputError."""
    if not (math.isfinite(stamp_s) and math.isfinite(range_m) and range_m > 0.0):
        raise InputError(f"range sample must have a finite stamp and a finite range > 0, got {range_m}")
    return RangeMeasurement(stamp_s=float(stamp_s), range_m=float(range_m))


def check_yaw(stamp_s: float, yaw_rad: float, variance_rad2: float = 0.0) -> YawMeasurement:
    """Validated yaw sample (finite stamp and yaw, a finite variance >= 0) or InputError."""
    if not (math.isfinite(stamp_s) and math.isfinite(yaw_rad)):
        raise InputError(f"yaw sample must be finite, got stamp {stamp_s}, yaw {yaw_rad}")
    if not (math.isfinite(variance_rad2) and variance_rad2 >= 0.0):
        raise InputError(f"yaw sample's variance must be finite and >= 0, got {variance_rad2}")
    return YawMeasurement(stamp_s=float(stamp_s), yaw_rad=float(yaw_rad), variance_rad2=float(variance_rad2))


def check_frame(stamp_s: float, image: npt.ArrayLike, shape: tuple[int, int]) -> FrameMeasurement:
    """Validated grey frame of the camera's ``(height, width)`` or InputError."""
    img = check_grey_image(image, "image", min_side_px=8)
    if img.shape != shape:
        raise InputError(f"frame must have shape {shape} (height, width), got {img.shape}")
    if not math.isfinite(stamp_s):
        raise InputError("frame stamp must be finite")
    return FrameMeasurement(stamp_s=float(stamp_s), image=img)


def sensor_of(measurement: Measurement) -> Sensor:
    """The stream a measurement belongs to (InputError for anything else)."""
    if isinstance(measurement, ImuMeasurement):
        return Sensor.IMU
    if isinstance(measurement, RangeMeasurement):
        return Sensor.RANGE
    if isinstance(measurement, YawMeasurement):
        return Sensor.YAW
    if isinstance(measurement, FrameMeasurement):
        return Sensor.CAMERA
    raise InputError(f"unknown measurement type {type(measurement).__name__}")
