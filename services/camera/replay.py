"""Replay of a recorded input (image folder, bag, EuRoC folder, capataz recording) by the camera service.

Samples go out in stamp order with their own stamps (the sensor's time base). Frames are paced at the
recorded rate times ``--rate`` or, with ``--rate 0`` / ``--fps 0``, go out as fast as they are consumed
(``--in-flight K`` is the flow control: at most K frames without a published yaw). The IMU and range
samples up to a frame are held back and go out just before it, as the simulated camera sends them (sent as
soon as read, samples newer than a frame could reach the estimator first and make it refuse that frame as
stale). ``--loop`` replays again, stamps shifted by the recording's span (first to last sample) plus one
frame period, so stamps keep increasing.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import TYPE_CHECKING

from common.errors import InputError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, Measurement, RangeMeasurement
from services.camera.sources import RecordedSource
from services.estimator.sim_publisher import message_of

if TYPE_CHECKING:
    from services.camera.service import CameraService

logger = logging.getLogger(__name__)

#: the camera's publisher of each measurement type
_TOPICS = {FrameMeasurement: "camera", ImuMeasurement: "imu", RangeMeasurement: "range"}


class LoopedStamps:
    """The stamp offset of an input replayed in rounds (``--loop``): each round begins one frame period after
    the previous round's last sample, so that stamps keep increasing (receivers refuse a stamp that is not
    after the one before). The simulated flight and the recorded replay both shift their stamps with it."""

    def __init__(self, default_period_s: float = 0.05) -> None:
        self.offset_s = 0.0
        #: the first sample's stamp (first round, offset 0); None before the first sample
        self.first_s: float | None = None
        self._last_s = 0.0  # the last sample's shifted stamp
        self._last_frame_s: float | None = None  # the last frame's shifted stamp
        self._period_s = default_period_s  # the latest frame period seen

    def offset_of(self, stamp_s: float, frame: bool = True) -> float:
        """The offset to add to this sample's recorded stamp (samples in order; ``frame``: a camera frame,
        whose spacing is the frame period)."""
        shifted = stamp_s + self.offset_s
        if self.first_s is None:
            self.first_s = shifted
        if frame:
            if self._last_frame_s is not None and shifted > self._last_frame_s:
                self._period_s = shifted - self._last_frame_s
            self._last_frame_s = shifted
        self._last_s = shifted
        return self.offset_s

    def next_round(self) -> None:
        self.offset_s = self._last_s + self._period_s - (self.first_s or 0.0)


def replay_recording(service: CameraService, source: RecordedSource) -> None:
    """Publish ``source`` on every UAV stream of ``service``, then mark the service finished. A recording
    found broken half-way (a truncated bag, an image changed since it was checked) stops the replay with
    one logged line and the ``recording_errors`` counter (the camera then exits with code 1)."""
    try:
        _replay(service, source)
    except InputError as exc:
        service.count_error("recording_errors", "replay stopped", exc)
    service.finished.set()
    service.stop_event.set()


def _replay(service: CameraService, source: RecordedSource) -> None:
    settings = service.settings
    paced = settings.fps > 0 and settings.rate > 0
    logger.info("replaying %s%s", source.description, f" at {settings.rate:g}x" if paced else ", unpaced")
    if source.camera_info is not None:
        logger.info("camera calibration: %s", source.camera_info)
    seq = {"camera": -1, "imu": -1, "range": -1}
    pending: list[Measurement] = []  # sensor samples read since the last frame, stamps shifted
    stamps = LoopedStamps()
    t_wall0 = time.monotonic()
    skip = lambda kind, why: service.count_error(f"skipped_{kind}", "sample skipped", why)  # noqa: E731
    while not service.stop_event.is_set():
        for m in source.measurements(skip):
            if service.stop_event.is_set():
                break
            first = stamps.first_s is None
            stamp_s = m.stamp_s + stamps.offset_of(m.stamp_s, frame=isinstance(m, FrameMeasurement))
            if first:
                t_wall0 = time.monotonic()
            shifted = replace(m, stamp_s=stamp_s)
            if not isinstance(shifted, FrameMeasurement):
                if settings.sensors:
                    pending.append(shifted)
                continue
            if paced:
                delay = t_wall0 + (stamp_s - (stamps.first_s or 0.0)) / settings.rate - time.monotonic()
                if delay > 0 and service.stop_event.wait(delay):
                    break
            _publish_sensors(service, pending, seq)  # just before their frame, as the simulated camera does
            pending.clear()
            seq["camera"] += 1
            for uav in settings.uavs:
                service._wait_yaw(uav, seq["camera"] - 1)
                service._put(uav, "camera", message_of(uav, seq["camera"], shifted)[1])
            service.counters.inc("frames_out")
        if not settings.loop or seq["camera"] < 0:
            break
        stamps.next_round()
    _publish_sensors(service, pending, seq)  # samples after the last frame
    for uav in settings.uavs:
        service._wait_yaw(uav, seq["camera"])


def _publish_sensors(service: CameraService, samples: list[Measurement], seq: dict[str, int]) -> None:
    for m in samples:
        topic = _TOPICS[type(m)]
        seq[topic] += 1
        for uav in service.settings.uavs:
            service._put(uav, topic, message_of(uav, seq[topic], m)[1])
