"""What every reader yields: a time-ordered stream of measurements plus what is known about the camera."""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator

import cv2
import numpy as np

from common.errors import InputError
from common.estimation.measurements import SENSOR_ORDER, Measurement, sensor_of


def to_grey_u8(image: np.ndarray, encoding: str, what: str) -> np.ndarray:
    """A (H, W) uint8 grey image from a decoded ``mono8``, ``mono16``, ``bgr8`` or ``rgb8`` array.

    ``mono16`` keeps its 8 most significant bits (``>> 8``): a fixed mapping, so brightness does not
    flicker frame to frame the way a per-frame normalization would.
    """
    if encoding == "mono8" and image.ndim == 2:
        return np.ascontiguousarray(image, dtype=np.uint8)
    if encoding == "mono16" and image.ndim == 2:
        return np.ascontiguousarray(image.astype(np.uint16) >> 8, dtype=np.uint8)
    if encoding in ("bgr8", "rgb8") and image.ndim == 3 and image.shape[2] == 3:
        code = cv2.COLOR_BGR2GRAY if encoding == "bgr8" else cv2.COLOR_RGB2GRAY
        return np.ascontiguousarray(cv2.cvtColor(np.ascontiguousarray(image), code))
    raise InputError(f"{what}: cannot convert a {image.shape} image of encoding {encoding!r} to grey")


def in_stamp_order(
    measurements: Iterable[tuple[float, Measurement]], window: int = 64
) -> Iterator[Measurement]:
    """Re-order measurements given in log (arrival) order by their sensor stamps, within ``window`` items.

    A bag is sorted by the time each message was logged; a sensor's stamp can lag by its latency. A
    bounded heap puts them back in stamp order (memory: ``window`` messages). Equal stamps go in
    :data:`~common.estimation.measurements.SENSOR_ORDER` (range, IMU, frame), the simulated stream's.
    """
    heap: list[tuple[float, int, int, Measurement]] = []
    for n, (stamp_s, m) in enumerate(measurements):
        heapq.heappush(heap, (stamp_s, SENSOR_ORDER[sensor_of(m)], n, m))
        if len(heap) > window:
            yield heapq.heappop(heap)[3]
    while heap:
        yield heapq.heappop(heap)[3]
