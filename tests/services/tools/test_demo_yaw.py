from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.sim.flight import hover_flight
from common.yaw import YawSettings
from services.tools.demo_yaw import report_yaw, track_frames


def test_report_yaw_writes_plot_and_json_from_estimates_and_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flight = hover_flight(seed=0, n_frames=140)
    run = track_frames(flight.frames(), YawSettings())
    summary = report_yaw(
        tmp_path,
        flight.frame_stamps_s,
        run.yaw_rad,
        flight.yaw_rad,
        ms_per_frame=run.ms_per_frame,
        stem="yaw_test",
    )
    assert (tmp_path / "yaw_test.png").stat().st_size > 10_000
    stored = json.loads((tmp_path / "yaw_test.json").read_text())
    assert stored["summary"]["frames"] == 140
    assert len(stored["series"]["ame_deg"]) == 140 - 100
    assert summary["max_ame_deg"] == pytest.approx(max(stored["series"]["ame_deg"]))
    assert summary["max_ame_deg"] < 0.5
    assert "max accumulated mean error" in capsys.readouterr().out


def test_report_yaw_sees_a_wrong_estimate(tmp_path: Path) -> None:
    stamps = np.arange(300) / 20.0
    truth = np.radians(np.linspace(0.0, 30.0, 300))
    drifting = truth - truth[0] + np.radians(np.linspace(0.0, 6.0, 300))
    summary = report_yaw(tmp_path, stamps, drifting, truth)
    assert summary["final_deg"] == pytest.approx(6.0)
    assert summary["max_ame_deg"] > 1.0
