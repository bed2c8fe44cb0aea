"""``capataz bench ros2`` runs end to end (a short run, its own process): every stream is sent at its rate,
arrives through the bridge, and the JSON holds the rates and latencies the table shows."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from services.ros2 import extra_installed

ROOT = Path(__file__).resolve().parents[3]
NO_EXTRA = "ros2 extra not installed (pip install 'capataz[ros2]')"
pytestmark = [pytest.mark.zenoh, pytest.mark.ros2, pytest.mark.skipif(not extra_installed(), reason=NO_EXTRA)]

STREAMS = ("in camera", "in imu", "out yaw", "out attitude", "out pose/vo", "out pose/pf")


def test_a_short_bench_run_measures_every_stream_through_the_bridge(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "services.tools.cli", "bench", "--out", str(tmp_path), "ros2",
               "--seconds", "3", "--warmup", "0.5", "--fps", "10", "--imu-hz", "100"]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=180)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((tmp_path / "ros2.json").read_text())
    assert set(report["streams"]) == set(STREAMS)
    for name, stream in report["streams"].items():
        assert stream["sent"] >= 0.5 * stream["target_hz"] * 2.5, (name, stream)
        assert 0 < stream["received"] <= stream["sent"], (name, stream)
        assert 0 < stream["latency_median_ms"] <= stream["latency_p99_ms"], (name, stream)
    assert "p99 ms" in result.stdout and "in camera" in result.stdout
