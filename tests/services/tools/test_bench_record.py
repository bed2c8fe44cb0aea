"""``capataz bench record`` on a short run: both modes measured, the recorder exits 0 and its file holds
the run's frames (the figure itself is noise on a shared host and is not asserted)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pytest

from services.tools.bench import record

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]


def test_bench_record_measures_both_modes(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    record.add_arguments(parser)
    args = parser.parse_args(["--frames", "30", "--repeats", "1", "--warmup", "5"])
    args.out = tmp_path
    result = record.run(args)
    modes = {row["mode"]: row for row in result["table"]}
    assert set(modes) == {"no recorder", "with recorder"}
    assert all(row["frames"] > 0 and math.isfinite(row["median_ms"]) for row in modes.values())
    with_recorder = [r for r in result["runs"] if r["recorder"]]
    assert with_recorder and all(
        r["recorder_exit"] == 0 and r["recorded_frames"] >= 25 for r in with_recorder
    )
    assert result["budget_ms"] == 50.0
