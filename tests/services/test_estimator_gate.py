"""The estimator's inputs through the one input gate: a frame whose seq jumps and frames of a second sender
are refused and counted, and the flight's poses are the same bits as without them (issue 27)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from common.estimation.measurements import FrameMeasurement, Measurement
from common.sim.flight import Flight, turns_flight
from common.sim.stream import flight_measurements
from common.wire.codec import decode, encode
from common.wire.measurements import message_of
from common.wire.messages import Frame, PoseEstimate
from services.estimator import EstimatorService
from services.runtime.transport import TransportSettings
from tests.services.fakes import FakeBytes, FakePublisher
from tests.services.test_estimator_behind import _callback, _settings

N_FRAMES = 120
CAMERA = SimpleNamespace(source_id=SimpleNamespace(zid="c0ffee", eid=1))
FORGER = SimpleNamespace(source_id=SimpleNamespace(zid="bad", eid=7))


@pytest.fixture(scope="module")
def flight() -> Flight:
    return turns_flight(seed=0)


def _sample(message: Any, key: str, source: SimpleNamespace) -> SimpleNamespace:
    payload, attachment = encode(message)
    return SimpleNamespace(
        payload=FakeBytes(payload), attachment=FakeBytes(attachment), key_expr=key, source_info=source
    )


def _run(flight: Flight, stream: list[Measurement], hostile: bool) -> EstimatorService:
    """The stream through the callbacks, one estimator turn after each frame; ``hostile``: after frame 70 a
    frame with seq 2**53 (the next frame's pixels), after frames 80-82 the next frame shifted by 6 px from
    a second sender with the camera's UAV id and the next seq."""
    service = EstimatorService("gate", 0, TransportSettings(), _settings(flight))
    service._attitude_pub, service._pose_pub = FakePublisher(), FakePublisher()  # type: ignore[assignment]
    frames = 0
    for seq, m in enumerate(stream):
        key, message = message_of("uav0", seq, m)
        _callback(service, m)(_sample(message, key, CAMERA))
        if not isinstance(m, FrameMeasurement):
            continue
        frames += 1
        assert service.step(0.0)
        if hostile and isinstance(message, Frame) and frames in (70, 80, 81, 82):
            forged = message.model_copy(
                update={"seq": 2**53 if frames == 70 else seq + 1, "stamp_s": message.stamp_s + 0.01}
            )
            if frames != 70:
                forged = forged.model_copy(update={"pixels": np.roll(message.pixels, 6, axis=1)})
            _callback(service, m)(_sample(forged, key, CAMERA if frames == 70 else FORGER))
            service.step(0.0)
    while service.step(0.0):
        pass
    return service


def test_a_seq_jump_and_a_second_sender_leave_the_estimator_poses_unchanged(flight: Flight) -> None:
    """Regression (issue 27): the estimator had no frame gate; a frame with seq 2**53 took its final error
    from 0.73 to 3.5 cm and three shifted frames from a second sender drove it 37.7 cm off."""
    stream = list(flight_measurements(flight, 0, N_FRAMES))
    clean = _run(flight, stream, hostile=False)
    attacked = _run(flight, stream, hostile=True)
    counts = attacked.counters.counts()
    assert counts.get("refused_camera_seq_jump") == 1, counts
    assert counts.get("refused_camera_foreign_sender") == 3, counts
    assert counts.get("frames_in") == clean.counters.get("frames_in") == N_FRAMES

    def poses(service: EstimatorService) -> list[PoseEstimate]:
        return [decode(p, a, PoseEstimate) for p, a in service._pose_pub.puts]  # type: ignore[attr-defined]

    clean_poses, attacked_poses = poses(clean), poses(attacked)
    assert [p.stamp_s for p in attacked_poses] == [p.stamp_s for p in clean_poses]
    for a, c in zip(attacked_poses, clean_poses, strict=True):
        assert np.array_equal(a.p_world_body_m, c.p_world_body_m)
    assert not attacked.healthy()[0] and "inputs refused" in attacked.healthy()[1]
