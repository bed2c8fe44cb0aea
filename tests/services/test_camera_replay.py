"""The camera's replay of a recorded input (services/camera/replay.py), without Zenoh: what is published,
in which order, with which stamps; ``--loop`` keeps stamps increasing; ``--no-sensors`` sends frames only."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from common.estimation.measurements import FrameMeasurement, ImuMeasurement, RangeMeasurement
from services.camera.replay import replay_recording
from services.camera.settings import CameraSettings
from services.camera.sources import RecordedSource
from services.runtime.handoff import Counters


class _Camera:
    """The part of CameraService that replay_recording uses, recording every put."""

    def __init__(self, settings: CameraSettings, stop_after_frames: int | None = None) -> None:
        self.settings = settings
        self.stop_event = threading.Event()
        self.finished = threading.Event()
        self.counters = Counters()
        self.puts: list[tuple[str, str, Any]] = []
        self.stop_after_frames = stop_after_frames

    def _wait_yaw(self, uav: str, seq: int) -> None:
        pass

    def _put(self, uav: str, topic: str, message: Any) -> None:
        self.puts.append((uav, topic, message))
        frames = sum(1 for _, t, _ in self.puts if t == "camera")
        if self.stop_after_frames is not None and frames >= self.stop_after_frames:
            self.stop_event.set()

    def count_error(self, counter: str, what: str, exc: Any) -> None:
        self.counters.inc(counter)


def _source() -> RecordedSource:
    image = np.zeros((4, 6), np.uint8)
    items = [
        ImuMeasurement(0.99, np.zeros(3), np.zeros(3)),
        RangeMeasurement(0.995, 1.5),
        FrameMeasurement(1.0, image),
        ImuMeasurement(1.04, np.ones(3), np.ones(3)),
        FrameMeasurement(1.05, image + 1),
    ]
    return RecordedSource("test", lambda _skip: iter(items), frames=2, width=6, height=4)


def test_replay_publishes_in_stamp_order_with_the_recorded_stamps_on_every_uav() -> None:
    camera = _Camera(CameraSettings(uavs=("a", "b"), fps=0.0))
    replay_recording(camera, _source())  # type: ignore[arg-type]
    for uav in ("a", "b"):
        mine = [(t, m.seq, m.stamp_s) for u, t, m in camera.puts if u == uav]
        assert mine == [("imu", 0, 0.99), ("range", 0, 0.995), ("camera", 0, 1.0), ("imu", 1, 1.04),
                        ("camera", 1, 1.05)]  # fmt: skip
    assert camera.finished.is_set() and camera.counters.get("frames_out") == 2


def test_loop_shifts_each_round_by_its_span_plus_one_frame_period() -> None:
    camera = _Camera(CameraSettings(fps=0.0, loop=True, sensors=False), stop_after_frames=6)
    replay_recording(camera, _source())  # type: ignore[arg-type]
    stamps = [m.stamp_s for _, t, m in camera.puts if t == "camera"]
    assert [m.seq for _, t, m in camera.puts if t == "camera"] == list(range(6))
    # a round spans 0.99 (its first IMU sample) .. 1.05; the next starts one frame period (0.05 s) later
    assert np.allclose(stamps, [1.0, 1.05, 1.11, 1.16, 1.22, 1.27])
    assert all(t == "camera" for _, t, _ in camera.puts)  # --no-sensors


def test_a_recording_broken_half_way_stops_the_replay_with_one_counted_error() -> None:
    from common.datasets.rosbag import BagError

    def broken(_skip: Any) -> Any:
        yield FrameMeasurement(1.0, np.zeros((4, 6), np.uint8))
        raise BagError("bag.mcap: truncated or corrupt bag (EOFError)")

    camera = _Camera(CameraSettings(fps=0.0))
    replay_recording(camera, RecordedSource("broken", broken, frames=2, width=6, height=4))  # type: ignore[arg-type]
    assert camera.counters.get("recording_errors") == 1 and camera.counters.get("frames_out") == 1
    assert camera.finished.is_set() and camera.stop_event.is_set()


def test_looped_simulated_flight_stamps_keep_increasing_across_rounds() -> None:
    """Regression: the simulated camera's --loop restarted each round's stamps at 0 (the first frame of a
    round had offset 0, later ones a growing one), so receivers refused half the second round as stale."""
    from services.camera.replay import LoopedStamps

    flight_s = [0.0, 0.05, 0.1, 0.15]
    stamps = LoopedStamps()
    published = []
    for _round in range(3):
        for t in flight_s:
            published.append(t + stamps.offset_of(t))
        stamps.next_round()
    assert np.allclose(np.diff(published), 0.05)
    assert np.isclose(published[0], 0.0)
