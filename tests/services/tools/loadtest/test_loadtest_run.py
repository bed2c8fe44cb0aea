"""``capataz loadtest`` end to end on a small cluster: the report has the issue's fields, hostile messages
and a killed worker are survived, and a breached objective gives exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from services.tools.cli import main

pytestmark = [pytest.mark.zenoh]


def test_a_short_run_with_faults_writes_the_report_and_judges_the_objectives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cluster = tmp_path / "c.yml"
    cluster.write_text("name: small\nhosts:\n  - name: h1\n    workers: 1\n  - name: h2\n    workers: 1\n")
    code = main([
        "loadtest", "--cluster", str(cluster), "--streams", "1", "--fps", "10", "--duration", "8",
        "--fault", "hostile:seq@2s", "--fault", "hostile:size@2.5s", "--fault", "hostile:sender@3s",
        "--fault", "kill:worker@4s",
        "--slo", "lost_pct<=100", "--slo", "p99_ms<=0.001", "--out", str(tmp_path / "out"), "--name", "t",
        "--warmup", "1",
    ])  # fmt: skip
    assert code == 2  # p99 <= 1 us cannot be met: breached, exit 2
    report = json.loads((tmp_path / "out" / "t.json").read_text())
    assert (tmp_path / "out" / "t.png").is_file()
    assert {"streams", "fps", "duration_s", "slo_passed", "per_stream", "faults", "cpu_s"} <= set(report)
    (stream,) = report["per_stream"]
    assert {"published", "received", "lost", "reported_dropped", "latency_ms", "warmup"} <= set(stream)
    assert stream["warmup"]["published"] == 10  # 1 s at 10 fps before the clock, reported apart
    # who computed the frames: the cluster's share of the patches and the frames the master did alone
    assert 0.0 <= stream["cluster_share"] <= 1.0 and 0 <= stream["frames_master_alone"] <= stream["received"]
    assert report["counters"]["master/m0/0"]["frames_in"] >= 80  # the services' counters of the run
    assert set(stream["latency_ms"]) == {"p50", "p95", "p99", "max"}
    assert stream["published"] == 80 and stream["received"] >= 70  # the cluster served through the faults
    faults = ["hostile:seq@2s", "hostile:size@2.5s", "hostile:sender@3s", "kill:worker@4s"]
    assert [f["fault"] for f in report["faults"]] == faults
    for fault in report["faults"]:
        assert {"lost", "gap_s", "recovery_s", "yaw_discontinuity_deg"} <= set(fault)
        assert fault["applied_at_s"] is not None and not str(fault["hit"]).startswith("failed")
    assert stream["max_yaw_jump_deg"] < 1.0  # the hostile frames did not move the yaw
    master = report["counters"]["master/m0/0"]
    # the gate refused them
    assert master["refused_camera_seq_jump"] == 1 and master["refused_camera_wrong_size"] == 2
    # the second sender's 3 frames (the camera's next seq numbers) were refused as such, none adopted
    assert master.get("frames_foreign", 0) + master.get("refused_camera_foreign_sender", 0) == 3
    assert report["faults"][2]["lost"] == 0
    verdicts = {o["objective"]: o["met"] for o in report["objectives"]}
    assert verdicts == {"lost_pct<=100": True, "p99_ms<=0.001": False} and report["slo_passed"] is False
    assert "BREACHED" in capsys.readouterr().out


def test_a_bad_schedule_is_one_clear_error(tmp_path: Path) -> None:
    assert main(["loadtest", "--fault", "explode:worker@3s", "--out", str(tmp_path)]) == 1
    assert main(["loadtest", "--duration", "5", "--fault", "kill:worker@9s", "--out", str(tmp_path)]) == 1
