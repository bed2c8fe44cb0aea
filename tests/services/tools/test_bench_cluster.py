"""The cluster benchmark's frame folders and its reply hand-off measurement."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from services.tools.bench.cluster import add_arguments
from services.tools.bench.cluster_overhead import cpu_steal_ticks, reply_handoff, steal_percent
from services.tools.bench.cluster_workload import write_frame_folder


def test_frame_folder_holds_only_this_runs_frames(tmp_path: Path) -> None:
    """Regression: a longer earlier run's frames stayed in the folder, so the camera replayed them too and
    the overhead run reported a negative number of lost frames."""
    rng = np.random.default_rng(0)
    write_frame_folder(tmp_path, [rng.integers(0, 255, (8, 8), dtype=np.uint8) for _ in range(5)])
    frames = [rng.integers(0, 255, (8, 8), dtype=np.uint8) for _ in range(3)]
    write_frame_folder(tmp_path, frames)
    files = sorted(tmp_path.glob("*.pgm"))
    assert [f.name for f in files] == ["00000.pgm", "00001.pgm", "00002.pgm"]
    for path, frame in zip(files, frames, strict=True):
        assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), frame)


@pytest.mark.zenoh
def test_reply_handoff_times_both_ways_of_receiving_a_workers_reply(tmp_path: Path) -> None:
    result = reply_handoff(tmp_path, shm=False, requests=8, blocks=2)
    assert result["requests_per_mode"] == 8
    assert result["callback_ms"] > 0 and result["channel_ms"] > 0
    assert result["saved_ms"] == result["callback_ms"] - result["channel_ms"]


def test_steal_percent_is_the_stolen_share_of_cpu_time_between_two_readings() -> None:
    assert steal_percent((10, 1000), (30, 1400)) == 5.0
    assert np.isnan(steal_percent(None, (30, 1400)))
    assert np.isnan(steal_percent((10, 1000), (10, 1000)))  # no time passed
    reading = cpu_steal_ticks()  # Linux, where the services run
    assert reading is not None
    steal, total = reading
    assert 0 <= steal <= total


def test_count_options_refuse_what_would_measure_nothing() -> None:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args([]).overhead_repeats == 3
    for bad in (
        ["--overhead-repeats", "0"],
        ["--repeats", "x"],
        ["--overhead-frames", "15"],
        ["--warmup", "-1"],
    ):
        with pytest.raises(SystemExit):
            parser.parse_args(bad)
