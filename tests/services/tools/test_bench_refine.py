from __future__ import annotations

import argparse

from services.tools.bench import refine


def test_the_refine_bench_times_every_cap_against_every_patch_on_turned_pairs() -> None:
    parser = argparse.ArgumentParser()
    refine.add_arguments(parser)
    args = parser.parse_args(
        ["--resolution", "640x480", "--grid", "12x8", "--patch-size", "32", "--pyramid-level", "1",
         "--caps", "24", "--pairs", "2", "--repeats", "2"]
    )  # fmt: skip
    result = refine.run(args)
    rows = {row["refine_max_patches"]: row for row in result["table"]}
    assert list(rows) == [refine.BASELINE_CAP, 24]  # the baseline first, always measured
    for row in rows.values():
        assert row["refined"] == 2  # both pairs turn more than refine_min_deg
        for kind in ("in_process", "conclude"):
            assert 0 < row[f"{kind}_ms"] <= row[f"{kind}_ms_p95"]
        assert row["yaw_error_rms_deg"] < 0.05
    assert rows[refine.BASELINE_CAP]["conclude_vs_all"] == 1.0
    assert len(result["json"]["timed_ms"][24]["conclude"]) == 2
