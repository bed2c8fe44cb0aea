"""Regression: yaw jumps of 1.5-8 deg when the load-test harness fell behind.

Frames were stamped with the time they were sent: after a stall of the harness (a busy host) the late
frames went out in a burst a fraction of a millisecond apart, and the master's yaw tracker, whose rate
prior trusts the stamps, clamped their motion (in-process: 1.6-11 deg jumps, up to 34 deg drift over 60
frames). A frame is now stamped with its capture time (when it was due), as a camera stamps exposures."""

from __future__ import annotations

import itertools
import threading
import time
from typing import Any

import pytest

from common.wire.codec import decode
from common.wire.messages import Frame
from services.runtime.transport import TransportSettings, open_session
from services.tools.loadtest.frames import simulated_frames
from services.tools.loadtest.harness import RunSettings
from services.tools.loadtest.observers import StreamLog
from services.tools.loadtest.runner import _stream


class StallingPublisher:
    """A real publisher's id; ``put`` records the frame and stalls once, as a busy host does."""

    def __init__(self, publisher: Any, stall_at: int, stall_s: float) -> None:
        self.id = publisher.id
        self.frames: list[Frame] = []
        self.stall_at, self.stall_s = stall_at, stall_s

    def put(self, payload: bytes, attachment: bytes, source_info: Any) -> None:
        self.frames.append(decode(payload, attachment, Frame))
        if len(self.frames) == self.stall_at:
            time.sleep(self.stall_s)


@pytest.mark.zenoh
def test_yaw_jumps_when_the_harness_falls_behind_frames_keep_their_capture_stamps() -> None:
    settings = RunSettings(streams=1, fps=20.0, duration_s=1.0, warmup_s=0.0)
    loop = simulated_frames(8, seed=0)
    alone = TransportSettings(listen=(), connect=(), lease_ms=1000)
    with open_session(alone) as session:
        real = session.declare_publisher("test/loadtest/camera")
        stalling = StallingPublisher(real, stall_at=5, stall_s=0.3)  # six frame periods late
        logs = {"uav0": StreamLog("uav0")}

        class NoYaws:
            lock = threading.Condition()

        t_start = time.time() + 0.05
        _stream(settings, loop, logs, NoYaws(), {"uav0": stalling}, t_start, t_start, live=False)  # type: ignore[arg-type]
        real.undeclare()
    stamps = [f.stamp_s for f in stalling.frames]
    sent = [logs["uav0"].sent[k][0] for k in range(20)]
    assert [f.seq for f in stalling.frames] == list(range(20))
    # the frames after the stall went out in a burst (less than half a period apart) ...
    assert min(b - a for a, b in itertools.pairwise(sent)) < 0.5 / 20.0
    # ... but their stamps are their capture times, one period apart
    assert stamps == pytest.approx([t_start + k / 20.0 for k in range(20)], abs=1e-9)
