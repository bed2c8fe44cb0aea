from __future__ import annotations

import argparse

from services.tools.bench import yaw


def test_bench_yaw_reports_the_required_fields_on_a_short_run() -> None:
    parser = argparse.ArgumentParser()
    yaw.add_arguments(parser)
    args = parser.parse_args(["--frames", "40", "--quick", "--drop-step", "4"])
    result = yaw.run(args)
    for field in (
        "frames",
        "core_ms_median",
        "baseline_ms_median",
        "speedup",
        "core_max_ame_deg",
        "baseline_max_ame_deg",
        "core_final_yaw_error_deg",
        "baseline_best_grid",
        "fft_microbench_us",
    ):
        assert field in result, field
    assert result["frames"] == 40
    assert result["speedup"] == result["baseline_ms_median"] / result["core_ms_median"]
    assert abs(result["core_final_yaw_error_deg"]) < 0.5
    methods = [row["method"] for row in result["table"]]
    assert methods[0].startswith("core") and "baseline on the core's grid" in methods
    cores = [m for m in methods if m.startswith("core (")]
    assert cores == ["core (scipy fft)", "core (opencv fft)", "core (numpy fft)"]  # the default first
    assert {"numpy_forward_us", "scipy_forward_us", "opencv_forward_us"} <= set(result["fft_microbench_us"])
    assert "core, dropped frames" in methods and result["dropped_frames_step"] == 4
