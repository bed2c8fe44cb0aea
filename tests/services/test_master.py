"""The master's frame path without a cluster: admission, the frame queue, the yaw of each frame, health."""

from __future__ import annotations

import time
from typing import Any, cast

import cv2
import numpy as np
import pytest

from common.sim.flight import hover_flight
from common.wire.codec import encode
from common.wire.messages import Frame
from common.yaw import YawSettings
from services.master import MasterService, MasterSettings
from services.runtime.transport import TransportSettings
from tests.services.fakes import FakeBytes


class _Sample:
    def __init__(self, frame: Frame) -> None:
        payload, attachment = encode(frame)
        self.payload, self.attachment, self.key_expr = (
            FakeBytes(payload),
            FakeBytes(attachment),
            "capataz/uav/uav0/camera",
        )


def _master(frame_queue: int) -> MasterService:
    master = MasterService(
        "m", 0, TransportSettings(), MasterSettings(election=False, frame_queue=frame_queue)
    )
    master.session = cast(Any, object())  # no members: the master computes alone, no zenoh call is made
    return master


def test_dropped_frames_counts_each_drop_once() -> None:
    """Regression: YawEstimate.dropped_frames added the latest-wins drops to the seq gaps they caused, so
    every drop was counted twice."""
    flight = hover_flight(seed=0, n_frames=8)
    master = _master(frame_queue=2)
    frames = [
        Frame(uav="uav0", seq=k, stamp_s=k / 20, width=752, height=480, pixels=flight.frame(k))
        for k in range(6)
    ]
    estimates = []
    master._on_frame(_Sample(frames[0]))  # type: ignore[arg-type]
    master.intake.gate_received(leading=True)
    first = master.slot.take(0.0)
    assert first is not None
    estimates.append(master._estimate(*first, time.perf_counter()))
    for frame in frames[1:]:  # five frames while the master is busy: a queue of two drops the three oldest
        master._on_frame(_Sample(frame))  # type: ignore[arg-type]
    master.intake.gate_received(leading=True)
    while (item := master.slot.take(0.0)) is not None:
        estimates.append(master._estimate(*item, time.perf_counter()))
    assert [e.seq for e in estimates if e is not None] == [0, 4, 5]
    assert [e.dropped_frames for e in estimates if e is not None] == [0, 3, 3]
    assert master.counters.get("frames_dropped") == 3


def test_a_foreign_or_resized_frame_never_reaches_the_yaw_stage() -> None:
    master = _master(frame_queue=8)
    pixels = np.zeros((480, 752), np.uint8)
    master._on_frame(_Sample(Frame(uav="uav0", seq=0, stamp_s=0.0, width=752, height=480, pixels=pixels)))  # type: ignore[arg-type]
    master._on_frame(_Sample(Frame(uav="uav1", seq=1, stamp_s=0.05, width=752, height=480, pixels=pixels)))  # type: ignore[arg-type]
    small = np.zeros((64, 64), np.uint8)
    master._on_frame(_Sample(Frame(uav="uav0", seq=1, stamp_s=0.05, width=64, height=64, pixels=small)))  # type: ignore[arg-type]
    assert master.slot.depth() == 0 and master.counters.get("frames_in") == 0  # the callback only hands off
    master.intake.gate_received(leading=True)
    assert master.slot.depth() == 1
    assert (
        master.counters.get("refused_camera_foreign_uav") == 1
        and master.counters.get("refused_camera_wrong_size") == 1
    )
    ok, detail = master.healthy()
    assert not ok and "2 inputs refused" in detail


def test_a_bug_in_the_round_is_an_internal_error_with_its_traceback_not_a_routine_fallback_regression(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Issue 24: a broad ``except ValueError`` turned numpy bugs into a routine "local fallback". The frame is
    still computed here (never lost), but the bug is counted as ``internal_errors`` and logged with its
    traceback; an expected failure (a CapatazError) stays a ``local_fallback``."""
    import services.master.service as master_module
    from common.errors import CapatazError

    flight = hover_flight(seed=0, n_frames=3)
    frames = [
        Frame(uav="uav0", seq=k, stamp_s=k / 20, width=752, height=480, pixels=flight.frame(k))
        for k in range(3)
    ]
    real_merge = master_module.merge_measurements
    failures = iter([ValueError("operands could not be broadcast"), CapatazError("a member timed out")])

    def failing_merge(*args: Any, **kwargs: Any) -> Any:
        failure = next(failures, None)
        if failure is not None:
            raise failure
        return real_merge(*args, **kwargs)

    monkeypatch.setattr(master_module, "merge_measurements", failing_merge)
    master = _master(frame_queue=8)
    estimates = []
    for frame in frames:
        master._on_frame(_Sample(frame))  # type: ignore[arg-type]
        master.intake.gate_received(leading=True)
        item = master.slot.take(0.0)
        assert item is not None
        with caplog.at_level("ERROR"):
            estimates.append(master._estimate(*item, time.perf_counter()))
    assert all(e is not None for e in estimates[1:])  # frames 1 and 2 went through the failing rounds
    assert master.counters.get("internal_errors") == 1 and master.counters.get("local_fallback") == 1
    bug = [r for r in caplog.records if "internal error" in r.getMessage()]
    assert len(bug) == 1 and bug[0].exc_info is not None


@pytest.mark.parametrize(("given_level", "level", "stretch"), [(None, 2, 2.0), (1, 1, 1.0)])
def test_a_stream_works_at_the_level_of_its_frames_size_and_its_jobs_state_it(
    given_level: int | None, level: int, stretch: float
) -> None:
    """The default pyramid level follows the frame's size (1280x720: level 2, its pixel thresholds doubled),
    resolved once per stream: the tracker, the grid and the settings every job carries agree, so no member
    guesses it. A level given on the command line stays."""
    flight = hover_flight(seed=0, n_frames=2)
    pixels = [cv2.resize(flight.frame(k), (1280, 720), interpolation=cv2.INTER_LINEAR) for k in range(2)]
    master = MasterService(
        "m", 0, TransportSettings(),
        MasterSettings(election=False, yaw=YawSettings(pyramid_level=given_level)),
    )  # fmt: skip
    master.session = cast(Any, object())
    for k in range(2):
        frame = Frame(uav="uav0", seq=k, stamp_s=k / 20, width=1280, height=720, pixels=pixels[k])
        master._on_frame(_Sample(frame))  # type: ignore[arg-type]
        master.intake.gate_received(leading=True)
        item = master.slot.take(0.0)
        assert item is not None and master._estimate(*item, time.perf_counter()) is not None
    stream = master.stream
    assert stream is not None
    assert stream.grid.pyramid_level == stream.tracker.settings.pyramid_level == level
    assert stream.settings.pyramid_level == stream.wire_settings.pyramid_level == level
    default = YawSettings()
    assert stream.wire_settings.ransac_threshold_px == pytest.approx(stretch * default.ransac_threshold_px)
    assert stream.tracker.settings.max_residual_px == pytest.approx(stretch * default.max_residual_px)
