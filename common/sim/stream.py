"""A simulated flight as one time-ordered measurement stream: the one way a flight becomes sensor samples.

The estimator's replays and benchmarks feed it to the estimator in process, the camera service publishes it
(``capataz camera``), and the dataset tests export it as bags and EuRoC folders. Frames are rendered
lazily, one at a time, as the stream reaches them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from common.estimation.measurements import (
    SENSOR_ORDER,
    FrameMeasurement,
    ImuMeasurement,
    Measurement,
    RangeMeasurement,
    Sensor,
)
from common.sim.flight import Flight

#: sensor samples this close to the first or last frame's stamp belong to the stream (stamps are exact
#: multiples of each sensor's period, so this only absorbs rounding)
STAMP_TOLERANCE_S = 1e-9


def flight_measurements(
    flight: Flight, start_frame: int = 0, stop_frame: int | None = None
) -> Iterator[Measurement]:
    """The IMU, rangefinder and camera samples of frames ``[start_frame, stop_frame)`` and between them, in
    stamp order; equal stamps in :data:`~common.estimation.measurements.SENSOR_ORDER` (range, IMU, frame),
    so every sensor sample up to a frame's stamp comes before that frame. Sensor samples before the first
    frame or after the last one are not part of the stream. The IMU's samples carry its own clock's stamps
    (``flight.imu.stamps_s``) but come in the order of their true times, as a driver delivers them."""
    stop = flight.n_frames if stop_frame is None else min(int(stop_frame), flight.n_frames)
    t0 = float(flight.frame_stamps_s[start_frame])
    t1 = float(flight.frame_stamps_s[stop - 1])
    imu, rng = flight.imu, flight.range
    imu_rank, range_rank, camera_rank = (SENSOR_ORDER[s] for s in (Sensor.IMU, Sensor.RANGE, Sensor.CAMERA))
    events: list[tuple[float, int, int]] = []
    for rank, stamps in ((imu_rank, imu.true_stamps_s), (range_rank, rng.stamps_s)):
        inside = (stamps >= t0 - STAMP_TOLERANCE_S) & (stamps <= t1 + STAMP_TOLERANCE_S)
        events += [(float(stamps[i]), rank, i) for i in np.flatnonzero(inside).tolist()]
    events += [(float(flight.frame_stamps_s[i]), camera_rank, i) for i in range(start_frame, stop)]
    events.sort()
    for stamp_s, rank, i in events:
        if rank == imu_rank:
            yield ImuMeasurement(float(imu.stamps_s[i]), imu.gyro_rad_s[i], imu.accel_m_s2[i])
        elif rank == range_rank:
            yield RangeMeasurement(stamp_s, float(rng.range_m[i]))
        else:
            yield FrameMeasurement(stamp_s, flight.frame(i))
