"""Build the filter's compiled kernels before the estimator subscribes.

The bias-aware filter's kernels are compiled by numba on their first call (and cached on disk for the next
start). A cold compile took tens of seconds on a loaded host; an estimator that subscribed first met that
first call with its input queues filling: the IMU samples overflowed, the VO paired frames seconds apart,
and the filter diverged and did not come back (the docker end-to-end run on a loaded host: 13 VO poses in
90 s and a roll/pitch error of 37 deg RMS). So the service runs a throw-away estimator over a short
synthetic stretch (a level UAV at rest over a textured floor) first, before it declares any subscriber.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from common.estimation.coupling import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement
from common.estimation.ekf import STANDARD_GRAVITY_M_S2
from services.estimator.settings import EstimatorSettings, build_estimator

logger = logging.getLogger(__name__)

#: the synthetic stretch: IMU at 400 Hz, rangefinder at 40 Hz, frames at 20 Hz
_SECONDS, _IMU_HZ, _RANGE_HZ, _FRAME_HZ = 0.3, 400, 40, 20


def warm_up(settings: EstimatorSettings) -> float:
    """Run a throw-away estimator of these settings over 0.3 s at rest; returns the seconds it took
    (the compile on a cold cache, milliseconds on a warm one)."""
    t0 = time.perf_counter()
    estimator = build_estimator(settings)
    height, width = settings.height, settings.width
    floor = np.random.default_rng(0).integers(0, 256, (height, width), dtype=np.uint8)
    accel = np.array([0.0, 0.0, STANDARD_GRAVITY_M_S2])
    samples: list[Measurement] = [
        ImuMeasurement(k / _IMU_HZ, np.zeros(3), accel) for k in range(1, int(_SECONDS * _IMU_HZ))
    ]
    samples += [RangeMeasurement(k / _RANGE_HZ + 1e-4, 1.5) for k in range(int(_SECONDS * _RANGE_HZ))]
    samples += [FrameMeasurement(k / _FRAME_HZ + 2e-4, floor) for k in range(int(_SECONDS * _FRAME_HZ))]
    for sample in sorted(samples, key=lambda m: m.stamp_s):
        estimator.push(sample)
        estimator.process_due()
    estimator.drain()
    took_s = time.perf_counter() - t0
    logger.info("filter kernels ready in %.2f s", took_s)
    return took_s
