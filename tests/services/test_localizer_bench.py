"""``capataz bench localizer`` on a tiny flight: every reported field is there and consistent."""

from __future__ import annotations

import argparse
import os

from services.bench import localizer


def test_bench_reports_every_field_and_restores_the_cpu_affinity() -> None:
    parser = argparse.ArgumentParser()
    localizer.add_arguments(parser)
    args = parser.parse_args(
        ["--frames", "12", "--settle", "6", "--runs", "1", "--repeats", "1", "--timing-frames", "2"]
    )
    before = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    result = localizer.run(args)
    if before is not None:
        assert os.sched_getaffinity(0) == before
    for key in ("ms_per_step_200", "ms_per_step_1000", "baseline_ms_per_step_200", "speedup_200"):
        assert result[key] > 0.0
    assert result["speedup_200"] == result["baseline_ms_per_step_200"] / result["ms_per_step_200"]
    assert set(result["scorings"]) == {"klein_murray", "per_edge", "nearest_edge", "nearest_edge_dt"}
    for row in result["scorings"].values():
        assert {"ms_per_step_200", "position_rmse_cm", "yaw_rmse_deg"} <= set(row)
    best = result["fastest_scoring_meeting_goal"]
    if best is not None:
        assert result["scorings"][best]["meets_accuracy_goal"]
        assert all(
            row["ms_per_step_200"] >= result["scorings"][best]["ms_per_step_200"]
            for row in result["scorings"].values()
            if row["meets_accuracy_goal"]
        )
    assert len(result["table"]) == 6
