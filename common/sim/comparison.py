"""Paper C's flight (b) through the standard estimators: the comparison that the estimator demo
(``capataz run``) and its benchmark (``capataz bench estimator``) both make."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Unpack

from common.estimation.measurements import Measurement
from common.estimation.replay import CONFIGURATIONS, EstimatorRun, run_estimators, standard_estimators
from common.sim.flight import Flight, FlightOptions, turns_flight
from common.sim.stream import flight_measurements


def compare_on_flight_b(
    seed: int = 0,
    frames: int | None = None,
    start_frame: int = 0,
    names: tuple[str, ...] = tuple(CONFIGURATIONS),
    wrap: Callable[[Iterator[Measurement]], Iterator[Measurement]] = iter,
    **options: Unpack[FlightOptions],
) -> tuple[Flight, dict[str, EstimatorRun]]:
    """Flight (b) (deterministic by ``seed``) through the standard estimators ``names``, its frames rendered
    once; ``wrap`` sees the measurement stream on its way (the demo counts frames for its progress bar);
    ``options`` go to the flight (e.g. a mounted camera, the IMU's axes and clock offset).
    Callers that time it pin OpenCV to one thread first (``cv2.setNumThreads(1)``)."""
    flight = turns_flight(seed=seed, **options)
    stop = None if frames is None else start_frame + frames
    runs = run_estimators(
        standard_estimators(flight, start_frame, names), wrap(flight_measurements(flight, start_frame, stop))
    )
    return flight, runs
