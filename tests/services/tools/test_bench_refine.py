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


def test_the_warp_suite_finds_bilinears_bias_on_pure_turns_and_lanczos_without_it() -> None:
    """``--suite warp``: every interpolation on both floors, bilinear the baseline; on pure turns the
    refinement through bilinear reads turns off by several hundredths of a degree, through Lanczos by
    under a hundredth (what kept the measurement: common.yaw.stages.REFINE_INTERPOLATION)."""
    parser = argparse.ArgumentParser()
    refine.add_arguments(parser)
    result = refine.run(parser.parse_args(["--suite", "warp", "--pairs", "3", "--repeats", "1"]))
    rows = {(row["interpolation"], row["floor"]): row for row in result["table"]}
    assert set(rows) == {(i, f) for i in refine.INTERPOLATIONS for f in ("carpet", "checkerboard")}
    for floor in ("carpet", "checkerboard"):
        assert rows["bilinear", floor]["max_bias_deg"] > 0.03
        assert rows["lanczos", floor]["max_bias_deg"] < 0.012
        assert rows["bilinear", floor]["warp_vs_bilinear"] == 1.0
        assert 0 < rows["lanczos", floor]["warp_ms"] <= rows["lanczos", floor]["warp_ms_p95"]
    assert len(result["json"]["mean_errors_deg"]["lanczos"]["carpet"]) == len(refine.WARP_TURNS_DEG)
