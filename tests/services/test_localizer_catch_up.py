"""The localizer over Zenoh keeps the frames that arrive while the first frame is searched and catches up
through them in order: every frame gets its pose, the same as the in-process tracker's, none dropped."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from common.sim.objects import object_camera, rendered_object_flight
from common.wire.messages import PoseEstimate
from services.localizer import LocalizerService
from services.localizer.filters import StepInputs
from tests.services.localizer_harness import frame, in_process, linked, object_settings
from tests.zenoh_helpers import WAIT_S, hub, peer, put_message, wait_until

pytestmark = pytest.mark.zenoh

N_FRAMES = 16


def test_frames_arriving_during_the_first_search_are_all_tracked_in_order(tmp_path: Path) -> None:
    flight, images = rendered_object_flight(N_FRAMES, 3, object_camera())
    rvec, tvec = flight.pose(0).rvec_tvec()
    settings = object_settings(tmp_path, (*rvec.tolist(), *tvec.tolist()), 3)
    expected = in_process(settings, images, flight.times_s)
    assert all(s.status.value == "tracking" for s in expected)  # so a catch-up never ends early here

    with hub() as endpoint:
        service = LocalizerService("test", 0, peer(endpoint), settings, stats_period_s=0.2)
        step = service.path.step
        first = threading.Event()

        def long_first_search(inputs: StepInputs) -> PoseEstimate:
            # the first frame's search lasts until every other frame has arrived (a slow search on a busy
            # host: over 0.5 s, here the whole stream)
            if not first.is_set():
                first.set()
                wait_until(lambda: service.counters.get("frames_in") == N_FRAMES)
            return step(inputs)

        service.path.step = long_first_search  # type: ignore[method-assign]
        with linked(service, endpoint) as (publisher, poses):
            t0 = time.monotonic()
            for i, image in enumerate(images):  # at the flight's own rate (30 fps)
                time.sleep(max(0.0, float(flight.times_s[i] - flight.times_s[0]) - (time.monotonic() - t0)))
                put_message(publisher, frame(i, float(flight.times_s[i]), image))
            received = [poses.get(timeout=WAIT_S) for _ in range(N_FRAMES)]
    assert first.is_set()
    assert [p.seq for p in received] == list(range(N_FRAMES))
    for pose, state in zip(received, expected, strict=True):  # caught up with the stamps' intervals
        assert pose.tracking_state == "tracking"
        assert np.allclose(pose.p_world_body_m, state.pose.p_world_camera_m, atol=1e-9)
    counts = service.counters.counts()
    assert counts.get("dropped_frames", 0) == 0
    assert counts.get("backlog_overflow", 0) == 0
    assert counts.get("catch_ups") == 1
    assert counts.get("poses_out") == counts.get("frames_tracking") == N_FRAMES
