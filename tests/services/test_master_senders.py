"""Per-sender checks over real sessions: within a stream epoch the master refuses and counts the frames of a
second sender (zenoh's ``source_info``), and a camera restarted in a new session is a new epoch only once
the old one fell silent; the yaw goes on from the camera's frames alone."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import zenoh

from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import Frame, YawEstimate
from services.master import MasterService, MasterSettings
from services.runtime.transport import open_session, zbytes
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

FPS = 10.0


class Camera:
    """One camera session: frames of the hover flight, each declaring its sender like the camera service."""

    def __init__(self, endpoint: str) -> None:
        self.session = open_session(peer(endpoint))
        self.publisher = self.session.declare_publisher(keys.camera_key("uav0"))
        assert matched(self.publisher)

    def send(self, seq: int, pixels: np.ndarray) -> None:
        frame = Frame(uav="uav0", seq=seq, stamp_s=time.time(), width=752, height=480, pixels=pixels)
        payload, attachment = encode(frame)
        source = zenoh.SourceInfo(self.publisher.id, seq)
        self.publisher.put(payload, attachment=attachment, source_info=source)

    def close(self) -> None:
        self.publisher.undeclare()
        self.session.close()


@pytest.mark.zenoh
@pytest.mark.parametrize("trust", [False, True], ids=["gate-alone", "with-source-lock"])
def test_a_second_sender_is_refused_within_the_epoch_and_a_restarted_camera_starts_a_new_one(
    trust: bool,
) -> None:
    flight = hover_flight(seed=0, n_frames=40)
    noise = np.random.default_rng(0).integers(0, 255, (480, 752), dtype=np.uint8)
    with hub() as endpoint:
        master = MasterService("m", 0, peer(endpoint), MasterSettings(election=False, trust=trust))
        thread = threading.Thread(target=master.run, daemon=True)
        thread.start()
        yaws: list[tuple[int, float]] = []  # (seq, yaw) in arrival order

        def on_yaw(sample: zenoh.Sample) -> None:
            estimate = decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate)
            yaws.append((estimate.seq, estimate.yaw_rad))

        camera = forger = None
        try:
            assert master.started.wait(WAIT_S)
            with open_session(peer(endpoint)) as observer:
                sub = observer.declare_subscriber(keys.yaw_key("uav0"), on_yaw)
                camera, forger = Camera(endpoint), Camera(endpoint)
                # the camera opens the epoch; the forger sends the camera's next frame, noise, right before it
                for k in range(12):
                    if k >= 2:
                        forger.send(k, noise)
                    camera.send(k, flight.frame(k))
                    assert wait_until(lambda k=k: len(yaws) == k + 1)
                counts = master.counters
                assert counts.get("refused_camera_foreign_sender") + counts.get("frames_foreign") == 10
                if not trust:  # the gate alone saw (and refused) every forged frame
                    assert master.counters.get("refused_camera_foreign_sender") == 10
                assert master.counters.get("epochs") == 1
                assert master.counters.get("refused_camera_seq_backward") == 0  # no forged frame was adopted
                assert [seq for seq, _ in yaws] == list(range(12))
                # a restarted camera: a new session from seq 0, once the old one is gone
                camera.close()
                last = yaws[-1][1]
                restarted = Camera(endpoint)
                t_sent = time.monotonic()
                k = 0
                while master.counters.get("epochs") < 2:
                    assert time.monotonic() - t_sent < WAIT_S
                    restarted.send(k, flight.frame(12 + k))
                    k += 1
                    time.sleep(1 / FPS)
                assert wait_until(lambda: len(yaws) >= 13)
                assert yaws[12][0] < k and abs(yaws[12][1] - last) < 1e-9  # the new epoch continues the yaw
                restarted.close()
                forger.close()
                camera = forger = None
                sub.undeclare()
        finally:
            for cam in (camera, forger):
                if cam is not None:
                    cam.close()
            master.request_stop()
            thread.join(10.0)
