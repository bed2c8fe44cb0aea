"""``capataz bench estimator`` on 25 frames of flight (b) (mid-turn): the JSON fields and the table."""

from __future__ import annotations

import argparse
import math

from services.bench import estimator


def test_bench_reports_every_field_on_a_short_flight() -> None:
    parser = argparse.ArgumentParser()
    estimator.add_arguments(parser)
    result = estimator.run(
        parser.parse_args(["--start-frame", "400", "--frames", "25", "--ekf-steps", "500"])
    )
    for key in (
        "vo_ms_median",
        "ekf_us_per_step_median",
        "vo_final_error_cm",
        "vo_error_pct",
        "vo_error_pct_unrectified",
        "att_rmse_deg",
        "alt_rmse_cm",
        "path_length_m",
    ):
        assert math.isfinite(result[key]), key
        assert result[key] >= 0.0
    assert result["frames"] == 25
    assert result["vo_ms_median"] > 0.0 and result["ekf_us_per_step_median"] > 0.0
    assert result["att_rmse_deg"] < 1.0
    # the VO alone on truth-rectified frames: sub-millimetre over these 25 frames (~0.8 m)
    assert 0.0 <= result["vo_final_error_cm_true_attitude"] < 0.1
    assert result["alt_rmse_cm"] < 3.0
    assert {row["run"] for row in result["table"]} == {
        "rectified_true_attitude_vo_only",
        "rectified",
        "traditional",
        "raw_ekf_scale",
        "gyro_yaw",
        "ekf_step_us",
    }
