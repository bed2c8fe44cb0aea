"""The camera's one publish loop (services/camera/replay.py), without Zenoh: what is published, in which
order, with which stamps, for a recorded input and for the simulated flights; ``--loop`` keeps stamps (and
sequence numbers) increasing; ``--no-sensors`` sends frames only."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from common.camera import DistortionModel
from common.estimation.measurements import FrameMeasurement, ImuMeasurement, RangeMeasurement
from common.sim.field import FIELD_SCENARIOS, scenario_camera
from services.camera.replay import replay_source
from services.camera.settings import CameraSettings, FlightName
from services.camera.sources import CameraSource, Sample
from services.runtime.counters import Counters


class _Camera:
    """The part of CameraService that replay_source uses, recording every put."""

    def __init__(self, settings: CameraSettings, stop_after_frames: int | None = None) -> None:
        self.settings = settings
        self.stop_event = threading.Event()
        self.finished = threading.Event()
        self.counters = Counters()
        self.puts: list[tuple[str, str, Any]] = []
        self.stop_after_frames = stop_after_frames

    def wait_yaw(self, uav: str, seq: int) -> None:
        pass

    def put(self, uav: str, topic: str, message: Any) -> bool:
        self.puts.append((uav, topic, message))
        frames = sum(1 for _, t, _ in self.puts if t == "camera")
        if self.stop_after_frames is not None and frames >= self.stop_after_frames:
            self.stop_event.set()
        return True

    def count_error(self, counter: str, what: str, exc: Any) -> None:
        self.counters.inc(counter)


def _source() -> CameraSource:
    image = np.zeros((4, 6), np.uint8)
    items: list[Sample] = [
        ImuMeasurement(0.99, np.zeros(3), np.zeros(3)),
        RangeMeasurement(0.995, 1.5),
        FrameMeasurement(1.0, image),
        ImuMeasurement(1.04, np.ones(3), np.ones(3)),
        FrameMeasurement(1.05, image + 1),
    ]
    return CameraSource("test", lambda _skip: iter(items), frames=2, width=6, height=4)


def test_replay_publishes_in_stamp_order_with_the_recorded_stamps_on_every_uav() -> None:
    camera = _Camera(CameraSettings(uavs=("a", "b"), fps=0.0))
    replay_source(camera, _source())
    for uav in ("a", "b"):
        mine = [(t, m.seq, m.stamp_s) for u, t, m in camera.puts if u == uav]
        assert mine == [("imu", 0, 0.99), ("range", 0, 0.995), ("camera", 0, 1.0), ("imu", 1, 1.04),
                        ("camera", 1, 1.05)]  # fmt: skip
    assert camera.finished.is_set() and camera.counters.get("frames_out") == 2


def test_loop_shifts_each_round_by_its_span_plus_one_frame_period() -> None:
    camera = _Camera(CameraSettings(fps=0.0, loop=True, sensors=False), stop_after_frames=6)
    replay_source(camera, _source())
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
    replay_source(camera, CameraSource("broken", broken, frames=2, width=6, height=4))
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


def test_the_simulated_flight_goes_out_as_its_one_stream_with_each_frames_truth_after_it() -> None:
    from common.sim.stream import flight_measurements
    from services.camera.flights import flight_source, simulated_flight

    settings = CameraSettings(uavs=("a", "b"), frames=3, fps=0.0, width=64, height=48)
    camera = _Camera(settings)
    replay_source(camera, flight_source(settings))
    expected = list(flight_measurements(simulated_flight(settings)))
    topics = {FrameMeasurement: "camera", ImuMeasurement: "imu", RangeMeasurement: "range"}
    for uav in ("a", "b"):
        mine = [(t, m) for u, t, m in camera.puts if u == uav]
        assert [t for t, _ in mine if t != "truth"] == [topics[type(m)] for m in expected]
        assert [m.stamp_s for t, m in mine if t != "truth"] == [m.stamp_s for m in expected]
        frames = [m for t, m in mine if t == "camera"]
        images = [m.image for m in expected if isinstance(m, FrameMeasurement)]
        assert all(np.array_equal(f.pixels, image) for f, image in zip(frames, images, strict=True))
        # the truth right after its frame, with the frame's seq and stamp
        after_frames = [mine[i + 1][1] for i, (t, _) in enumerate(mine) if t == "camera"]
        assert [(m.seq, m.stamp_s, m.source) for m in after_frames] == [
            (f.seq, f.stamp_s, "truth") for f in frames
        ]
    assert camera.finished.is_set() and camera.counters.get("frames_out") == 3


def test_looped_office_flight_keeps_odometry_seq_and_stamps_increasing() -> None:
    """Regression: the office flight's odometry restarted at seq 0 each round of --loop (frames did not)."""
    from services.camera.flights import flight_source

    settings = CameraSettings(flight=FlightName.OFFICE, frames=3, fps=0.0, loop=True, width=64, height=48)
    camera = _Camera(settings, stop_after_frames=7)
    replay_source(camera, flight_source(settings))
    odometry = [m for _, t, m in camera.puts if t == "pose_vo"]
    frames = [m for _, t, m in camera.puts if t == "camera"]
    assert [m.seq for m in odometry] == [m.seq for m in frames] == list(range(7))
    assert [m.stamp_s for m in odometry] == [m.stamp_s for m in frames]
    assert np.all(np.diff([m.stamp_s for m in frames]) > 0)
    assert {m.source for m in odometry} == {"sim-odometry"}


@pytest.mark.parametrize(
    ("flight", "model"), [(FlightName.FIELD, DistortionModel.RADTAN), (FlightName.CHECKERBOARD, None)]
)
def test_a_field_flight_at_another_size_keeps_its_lens_regression(
    flight: FlightName, model: DistortionModel | None
) -> None:
    """Regression: ``--width``/``--height`` gave every flight a 90 deg pinhole, so the ``field`` scenario's
    120 deg wide angle became another lens (and its calibration with it). A field scenario keeps its own
    lens's view at any size, as ``bench yaw --field-size`` flies it."""
    from services.camera.flights import simulated_flight

    settings = CameraSettings(flight=flight, frames=2, width=640, height=480)
    camera = simulated_flight(settings).camera
    expected = scenario_camera(FIELD_SCENARIOS[flight.value], 640, 480)
    assert camera.shape == (480, 640) and camera.fx == pytest.approx(expected.fx)
    assert (camera.distortion.model if camera.is_distorted else None) == model
