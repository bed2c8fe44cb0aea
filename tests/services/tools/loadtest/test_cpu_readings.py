"""CPU seconds of the cluster's processes, the one reading the load test and the dispatch bench share."""

from __future__ import annotations

import subprocess
import sys

from services.tools.loadtest.harness import processes_cpu_seconds


def test_every_process_with_a_reading_is_read_and_a_reaped_one_is_left_out() -> None:
    busy = subprocess.Popen([sys.executable, "-c", "import sys; sum(range(3_000_000)); sys.stdin.read()"],
                            stdin=subprocess.PIPE)  # fmt: skip
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()  # reaped: its /proc entry is gone
    try:
        readings = processes_cpu_seconds({"busy": busy, "done": done})  # type: ignore[dict-item]
        assert set(readings) == {"busy"} and readings["busy"] >= 0.0
    finally:
        busy.communicate(b"")
