"""The wire message of a sensor measurement and the key it goes out on (the wire's side of
:mod:`common.estimation.measurements`): what the camera publishes for each sample of a stream, simulated or
recorded, and what tests publish to the estimator."""

from __future__ import annotations

from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement
from common.wire import keys
from common.wire.messages import Frame, ImuSample, RangeSample
from common.wire.schema import WireModel


def message_of(uav: str, seq: int, measurement: Measurement) -> tuple[str, WireModel]:
    """The key and wire message of one sample of ``uav``'s stream (TypeError for a yaw: not a sensor
    sample the camera publishes)."""
    if isinstance(measurement, ImuMeasurement):
        return keys.imu_key(uav), ImuSample(
            uav=uav, seq=seq, stamp_s=measurement.stamp_s,
            gyro_rad_s=measurement.gyro_rad_s, accel_m_s2=measurement.accel_m_s2,
        )  # fmt: skip
    if isinstance(measurement, RangeMeasurement):
        return keys.range_key(uav), RangeSample(
            uav=uav, seq=seq, stamp_s=measurement.stamp_s, range_m=measurement.range_m
        )
    if isinstance(measurement, FrameMeasurement):
        h, w = measurement.image.shape
        return keys.camera_key(uav), Frame(
            uav=uav, seq=seq, stamp_s=measurement.stamp_s, width=w, height=h, pixels=measurement.image
        )
    raise TypeError(f"cannot publish {type(measurement).__name__}")
