"""``capataz camera --wait-for localizer``: a camera that feeds a localizer (no master) waits for it before
its first frame, so a localizer that starts late still gets every frame (regression: the README's CAD-model
quick-start wrote no trajectory on a loaded host, where the localizer came up 8 s after the camera and the
camera, waiting for a master only, had played most of the video to nobody)."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from common.members import Role
from common.wire import keys
from services.camera import CameraService, CameraSettings
from services.runtime.transport import open_session
from tests.zenoh_helpers import WAIT_S, hub, peer, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 6
LATE_S = 1.5


def test_a_camera_waiting_for_a_localizer_gives_a_late_one_every_frame() -> None:
    received: list[float] = []

    def on_frame(_sample: zenoh.Sample) -> None:
        received.append(time.monotonic())

    with hub() as endpoint:
        settings = CameraSettings(
            frames=N_FRAMES, fps=20.0, sensors=False, wait_for=Role.LOCALIZER, wait_master_s=WAIT_S
        )
        camera = CameraService("c", 0, peer(endpoint), settings)
        thread = threading.Thread(target=camera.run, daemon=True)
        started = time.monotonic()
        thread.start()
        time.sleep(LATE_S)  # the localizer starts late
        with open_session(peer(endpoint)) as session:
            subscriber = session.declare_subscriber(keys.camera_key("uav0"), on_frame)
            token = session.liveliness().declare_token(f"{keys.ROOT}/alive/localizer/late/0")
            assert wait_until(lambda: len(received) >= N_FRAMES, WAIT_S), len(received)
            token.undeclare()
            subscriber.undeclare()
        camera.request_stop()
        thread.join(10.0)
    assert len(received) == N_FRAMES and min(received) - started >= LATE_S
    # it waited for the localizer, not for a master (none runs: that wait would end only after WAIT_S)
    assert min(received) - started < WAIT_S / 2
    assert not camera.counters.get("no_localizer")
