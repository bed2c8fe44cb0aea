"""The estimator's inputs as they come off the wire: each message's values checked once, as the measurement
the filter takes (:mod:`common.estimation.measurements`)."""

from __future__ import annotations

from common.estimation.measurements import Measurement, check_frame, check_imu, check_range, check_yaw
from common.wire.messages import Frame, ImuSample, RangeSample, YawEstimate

Input = ImuSample | RangeSample | YawEstimate | Frame

#: what a refusal's log line calls each sensor's sample
WHAT = {"imu": "IMU sample", "range": "range sample", "yaw": "yaw", "camera": "frame"}


def measurement_of(message: Input, shape: tuple[int, int]) -> Measurement:
    """The checked measurement of a decoded message (frames of the camera's ``shape``); InputError when its
    values are not usable (NaN, inf, a wrong shape)."""
    if isinstance(message, ImuSample):
        return check_imu(message.stamp_s, message.gyro_rad_s, message.accel_m_s2)
    if isinstance(message, RangeSample):
        return check_range(message.stamp_s, message.range_m)
    if isinstance(message, YawEstimate):
        return check_yaw(message.stamp_s, message.yaw_rad, message.yaw_variance_rad2)
    return check_frame(message.stamp_s, message.pixels, shape)
