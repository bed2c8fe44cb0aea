from __future__ import annotations

import argparse

from services.tools.bench import fft


def test_the_fft_bench_times_every_variant_and_checks_the_runs_bits() -> None:
    parser = argparse.ArgumentParser()
    fft.add_arguments(parser)
    # 300 patches of 32 px: three runs of 128 patches, so the runs differ from one batch
    args = parser.parse_args(["--sizes", "16", "32", "--patches", "300", "--repeats", "2", "--calls", "1"])
    result = fft.run(args)
    rows = result["table"]
    assert [(r["patch_px"], r["variant"]) for r in rows] == [
        (size, variant) for size in (16, 32) for variant in fft.VARIANTS
    ]
    for row in rows:
        for direction in fft.DIRECTIONS:
            assert 0 < row[f"{direction}_us"] <= row[f"{direction}_us_p95"]
        assert (row["bit_identical"] is True) == (row["variant"] == "runs")
        if row["variant"] == "scipy":  # single precision against numpy's double inside: float32's rounding
            assert 0.0 < row["max_relative_difference"] < 1e-5
        else:
            assert row["max_relative_difference"] is None
        if row["variant"] == "batch":
            assert row["forward_vs_batch"] == row["inverse_vs_batch"] == 1.0
    assert [r["run"] for r in rows if r["variant"] == "runs"] == [512, 128]
    assert [r["run"] for r in rows if r["variant"] == "scipy"] == [512, 128]
    runs_us = result["json"]["runs_us"]
    assert len(runs_us["32"]["runs"]["forward"]) == 2
