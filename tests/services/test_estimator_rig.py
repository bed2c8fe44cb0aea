"""The estimator follows the stream's rig (issue 26): a rig other than its options' is adopted (the filter
rebuilt with its camera and mount), one equal to them changes nothing, a frame naming a rig not received is
refused and counted, and camera or mount options override the stream's rig."""

from __future__ import annotations

import numpy as np

from common.camera import CameraModel
from common.geometry import R_BODY_CAMERA_DOWN
from common.rig import Rig
from common.sim.flight import turns_flight
from common.sim.stream import flight_measurements
from common.wire.measurements import message_of
from common.wire.messages import Frame
from services.estimator import EstimatorService, EstimatorSettings
from services.estimator.settings import configured_rig
from services.runtime.mount_options import MountOptions
from services.runtime.transport import TransportSettings
from tests.services.fakes import FakePublisher
from tests.services.test_estimator_behind import _callback
from tests.services.test_estimator_gate import CAMERA, _sample


def _service(settings: EstimatorSettings) -> EstimatorService:
    service = EstimatorService("rig", 0, TransportSettings(), settings)
    service._attitude_pub, service._pose_pub = FakePublisher(), FakePublisher()  # type: ignore[assignment]
    return service


def _feed(service: EstimatorService, rig_id: str | None, n_frames: int = 6) -> None:
    flight = turns_flight(seed=0)
    frames = 0
    for seq, m in enumerate(flight_measurements(flight, 0, n_frames)):
        key, message = message_of("uav0", seq, m)
        if isinstance(message, Frame):
            message = message.model_copy(update={"rig_id": rig_id})
            frames += 1
        _callback(service, m)(_sample(message, key, CAMERA))
        service.step(0.0)


def test_a_stream_rig_other_than_the_options_is_adopted_and_an_equal_one_changes_nothing() -> None:
    settings = EstimatorSettings()
    tilted = Rig(
        CameraModel.default(), R_BODY_CAMERA_DOWN @ np.array([[1.0, 0, 0], [0, 0.0, -1], [0, 1, 0.0]])
    )
    for rig, adopted in ((configured_rig(settings), 0), (tilted, 1)):
        service = _service(settings)
        assert service.rigs is not None
        service.rigs.add(rig)
        _feed(service, rig.rig_id)
        assert service.counters.get("rigs_adopted") == adopted
        assert np.array_equal(service.estimator.R_body_camera, rig.R_body_camera)
        assert service.counters.get("frames_in") == 6


def test_a_frame_naming_a_rig_not_received_is_refused() -> None:
    service = _service(EstimatorSettings())
    _feed(service, "0123456789abcdef")
    assert service.counters.get("refused_camera_unknown_rig") == 6
    assert not service.counters.get("frames_in")


def test_mount_options_override_the_stream_rig() -> None:
    service = _service(EstimatorSettings(rig_mount=MountOptions(imu_time_offset_s=0.01)))
    assert service.rigs is None  # the stream's rig is not followed
    _feed(service, "0123456789abcdef")
    assert service.counters.get("frames_in") == 6 and not service.counters.get("rigs_adopted")
