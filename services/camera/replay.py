"""The camera's one publish loop: a source's samples (a simulated flight, an image folder, a bag, a EuRoC
folder, a capataz recording) on every UAV stream, through the service's guarded publish.

Samples go out in stamp order with their own stamps (the sensor's time base). A simulated flight's frames
go out at ``--fps`` frames per second, a recording's at the recorded rate times ``--rate``; ``--fps 0``
(and a recording's ``--rate 0``) as fast as they are consumed (``--in-flight K`` is the flow control: at
most K frames without a published yaw). The IMU, range and odometry samples up to a frame are held back
and go out just before it (sent as soon as read, samples newer than a frame could reach the estimator
first and make it refuse that frame as stale); a simulated flight's true pose follows its frame.
``--loop`` replays again, stamps shifted by the source's span (first to last sample) plus one frame
period, so stamps keep increasing.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Protocol

import numpy as np

from common.errors import InputError
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, RangeMeasurement
from common.geometry import quaternion_from_euler
from common.wire.measurements import message_of
from common.wire.messages import PoseEstimate
from common.wire.schema import WireModel
from services.camera.settings import CameraSettings
from services.camera.sources import CameraSource, OdometrySample, OnSkip, Sample
from services.runtime.counters import Counters

logger = logging.getLogger(__name__)

#: the camera's publisher of each sample type (a frame's true pose goes on ``truth``)
TOPICS: dict[type, str] = {
    FrameMeasurement: "camera",
    ImuMeasurement: "imu",
    RangeMeasurement: "range",
    OdometrySample: "pose_vo",
}


class Publisher(Protocol):
    """What the loop needs of the camera service (tests give it a recording stand-in)."""

    @property
    def settings(self) -> CameraSettings: ...
    @property
    def stop_event(self) -> threading.Event: ...
    @property
    def finished(self) -> threading.Event: ...
    @property
    def counters(self) -> Counters: ...
    def count_error(self, counter: str, what: str, exc: BaseException | str) -> None: ...
    def wait_yaw(self, uav: str, seq: int) -> None:
        """Flow control: return once at most ``in_flight`` frames up to ``seq`` lack a yaw."""

    def put(self, uav: str, topic: str, message: WireModel) -> bool:
        """Publish on ``uav``'s ``topic``; False when the service is stopping."""


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


def replay_source(camera: Publisher, source: CameraSource) -> None:
    """Publish ``source`` on every UAV stream of ``camera``, then mark the camera finished. A recording
    found broken half-way (a truncated bag, an image changed since it was checked) stops the replay with
    one logged line and the ``recording_errors`` counter (the camera then exits with code 1)."""
    try:
        _replay(camera, source)
    except InputError as exc:
        camera.count_error("recording_errors", "replay stopped", exc)
    camera.finished.set()
    camera.stop_event.set()


def _replay(camera: Publisher, source: CameraSource) -> None:
    settings = camera.settings
    paced = settings.fps > 0 and (source.paced_by_fps or settings.rate > 0)
    pace = f"{settings.fps:g} fps" if source.paced_by_fps else f"{settings.rate:g}x"
    logger.info("replaying %s%s", source.description, f" at {pace}" if paced else ", unpaced")
    if source.camera_info is not None:
        logger.info("camera calibration: %s", source.camera_info)
    seq = dict.fromkeys(TOPICS.values(), -1)
    pending: list[Sample] = []  # samples read since the last frame, stamps shifted
    stamps = LoopedStamps()
    t_wall0 = time.monotonic()
    frames_out = 0
    skip = lambda kind, why: camera.count_error(f"skipped_{kind}", "sample skipped", why)  # noqa: E731
    while not camera.stop_event.is_set():
        for index, frame in enumerate(_frames(camera, source, stamps, pending, skip)):
            if frames_out == 0:
                t_wall0 = time.monotonic()
            if paced:
                due_s = (
                    frames_out / settings.fps
                    if source.paced_by_fps
                    else (frame.stamp_s - (stamps.first_s or 0.0)) / settings.rate
                )
                delay = t_wall0 + due_s - time.monotonic()
                if delay > 0 and camera.stop_event.wait(delay):
                    break
            _publish_samples(camera, pending, seq)  # just before their frame
            pending.clear()
            seq["camera"] += 1
            for uav in settings.uavs:
                camera.wait_yaw(uav, seq["camera"] - 1)
                camera.put(uav, "camera", message_of(uav, seq["camera"], frame)[1])
                if source.truth is not None:  # the simulation's ground truth (for views, recordings)
                    camera.put(uav, "truth", source.truth(uav, seq["camera"], frame.stamp_s, index))
            frames_out += 1
            camera.counters.inc("frames_out")
        if not settings.loop or seq["camera"] < 0:
            break
        stamps.next_round()
    _publish_samples(camera, pending, seq)  # samples after the last frame
    for uav in settings.uavs:
        camera.wait_yaw(uav, seq["camera"])


def _frames(
    camera: Publisher,
    source: CameraSource,
    stamps: LoopedStamps,
    pending: list[Sample],
    skip: OnSkip,
) -> Iterator[FrameMeasurement]:
    """One round of the source: its frames, stamps shifted; the samples before each are added to
    ``pending`` (kept only with ``--sensors``). Stops when the camera stops."""
    for m in source.measurements(skip):
        if camera.stop_event.is_set():
            return
        is_frame = isinstance(m, FrameMeasurement)
        shifted = replace(m, stamp_s=m.stamp_s + stamps.offset_of(m.stamp_s, frame=is_frame))
        if isinstance(shifted, FrameMeasurement):
            yield shifted
        elif camera.settings.sensors:
            pending.append(shifted)


def _publish_samples(camera: Publisher, samples: list[Sample], seq: dict[str, int]) -> None:
    for m in samples:
        topic = TOPICS[type(m)]
        seq[topic] += 1
        for uav in camera.settings.uavs:
            camera.put(uav, topic, _message(uav, seq[topic], m))


def _message(uav: str, seq: int, sample: Sample) -> WireModel:
    if isinstance(sample, OdometrySample):
        return PoseEstimate(
            uav=uav,
            seq=seq,
            stamp_s=sample.stamp_s,
            p_world_body_m=sample.p_world_body_m,
            q_world_body=quaternion_from_euler(*sample.euler_rad),
            covariance=np.eye(6) * 1e-4,
            source="sim-odometry",
        )
    return message_of(uav, seq, sample)[1]
