"""``capataz camera --frame-codec png``: the camera's frames reach a master-side decode (the codec every
service decodes with) bit-identical to the flight's images, compressed on the way."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import zenoh

from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Frame
from services.camera import CameraService, CameraSettings
from services.camera.flights import simulated_flight
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 4


def test_png_frames_reach_the_master_side_decode_bit_identical() -> None:
    received: list[tuple[Frame, int]] = []
    lock = threading.Lock()

    def on_frame(sample: zenoh.Sample) -> None:
        payload = zbytes(sample.payload) or b""
        frame = decode(payload, zbytes(sample.attachment), Frame)
        with lock:
            received.append((frame, len(payload)))

    settings = CameraSettings(
        frames=N_FRAMES, fps=20.0, sensors=False, wait_master_s=WAIT_S, frame_codec="png", in_flight=0
    )
    with hub() as endpoint, open_session(peer(endpoint)) as session:
        subscriber = session.declare_subscriber(keys.camera_key("uav0"), on_frame)
        token = session.liveliness().declare_token(f"{keys.ROOT}/alive/master/test/0")
        camera = CameraService("c", 0, peer(endpoint), settings)
        thread = threading.Thread(target=camera.run, daemon=True)
        thread.start()
        assert wait_until(lambda: len(received) >= N_FRAMES, WAIT_S), len(received)
        camera.request_stop()
        thread.join(WAIT_S)
        token.undeclare()
        subscriber.undeclare()
    flight = simulated_flight(settings)
    assert [frame.seq for frame, _ in received] == list(range(N_FRAMES))
    for frame, payload_bytes in received:
        expected = flight.frame(frame.seq)
        assert frame.encoding == "png" and frame.pixels.shape == expected.shape == (480, 752)
        assert np.array_equal(frame.pixels, expected)
        assert payload_bytes < expected.nbytes  # it travelled compressed
    assert camera.counters.get("frame_bytes_out") == sum(n for _, n in received)
