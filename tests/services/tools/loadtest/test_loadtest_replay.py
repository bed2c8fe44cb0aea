"""``capataz loadtest --replay``: N streams from one recording made the way ``capataz record`` makes them,
stamped with the wall clock, with the warm-up ramp reported apart."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.recordings.mcap import RecordingError, RecordingWriter
from common.sim.flight import hover_flight
from common.wire import keys
from common.wire.messages import Frame
from services.tools.cli import main
from services.tools.loadtest.frames import recorded_frames

#: the recording's own frame period (10 Hz): the replay's default rate
PERIOD_S = 0.1


def record(path: Path, n_frames: int = 24) -> list[np.ndarray]:
    """A recording of the hover flight's frames on uav7 (stamps from the flight's clock, not the wall's)."""
    flight = hover_flight(seed=3, n_frames=n_frames)
    writer = RecordingWriter(path)
    frames = []
    for i in range(n_frames):
        pixels = flight.frame(i)
        frame = Frame(uav="uav7", seq=i, stamp_s=i * PERIOD_S, width=752, height=480, pixels=pixels)
        writer.write(keys.camera_key("uav7"), frame, 1_000_000 + i)
        frames.append(pixels)
    writer.close()
    return frames


def test_a_recording_gives_its_frames_and_rate_without_a_truth(tmp_path: Path) -> None:
    frames = record(tmp_path / "r.mcap")
    loop = recorded_frames(tmp_path / "r.mcap", max_frames=10)
    assert len(loop.frames) == 10 and loop.shape == (480, 752)
    assert all(np.array_equal(a, b) for a, b in zip(loop.frames, frames[:10], strict=False))
    assert loop.recorded_fps == pytest.approx(1 / PERIOD_S)
    pixels, yaw = loop.at(10)  # ping-pong: 0..9, then 8, 7, ...
    assert np.array_equal(pixels, frames[8]) and math.isnan(yaw)
    (tmp_path / "not.mcap").write_bytes(b"not a recording at all")
    with pytest.raises(RecordingError):
        recorded_frames(tmp_path / "not.mcap")


def test_a_file_that_is_not_a_recording_is_one_clear_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "x.mcap").write_bytes(b"\x89MCAP0\r\n garbage")
    assert main(["loadtest", "--replay", str(tmp_path / "x.mcap"), "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "error:" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.zenoh
def test_two_streams_replay_one_recording_at_its_rate_stamped_with_the_wall_clock(tmp_path: Path) -> None:
    record(tmp_path / "r.mcap")
    cluster = tmp_path / "c.yml"
    cluster.write_text("name: small\nhosts:\n  - name: h1\n    workers: 1\n")
    code = main([
        "loadtest", "--cluster", str(cluster), "--replay", str(tmp_path / "r.mcap"), "--streams", "2",
        "--duration", "3", "--warmup", "1", "--slo", "lost_pct<=10", "--out", str(tmp_path / "out"),
        "--name", "replay",
    ])  # fmt: skip
    report = json.loads((tmp_path / "out" / "replay.json").read_text())
    assert report["fps"] == pytest.approx(1 / PERIOD_S)  # the recording's rate
    assert str(tmp_path / "r.mcap") in report["frames_source"]
    assert report["warmup_s"] == 1.0
    # the ramp: uav0 sends the whole warm-up (10 frames at 10 Hz), uav1 joins a quarter of it later
    assert [s["warmup"]["published"] for s in report["per_stream"]] == [10, 8]
    for stream in report["per_stream"]:
        assert stream["published"] == 30
        # frames played back and forth with the recording's stamps would be refused as going backwards:
        # stamped with the wall clock they go through (the objective allows 10 % for a busy host)
        assert stream["received"] >= 27
        assert stream["max_yaw_jump_deg"] is None  # a recording has no truth: continuity is not judged
        assert 0 < stream["latency_ms"]["p50"] < 1000
    assert code == 0 and report["slo_passed"] is True
