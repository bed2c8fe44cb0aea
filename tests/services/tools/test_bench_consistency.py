"""``capataz bench consistency --quick``: every suite's lines in the file and the table, held-out seeds."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from services.tools.bench import _runner, consistency


@pytest.mark.slow
def test_bench_consistency_quick_writes_every_suites_lines(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    args = parser.parse_args(["--quick"])
    args.out = tmp_path
    assert _runner(consistency)(args) == 0
    payload = json.loads((tmp_path / "consistency.json").read_text())
    assert payload["fit_seeds"] == [0] and payload["held_out_seeds"] == [1]
    held = payload["lines"]["held_out"]
    for line in ("yaw pair measured", "yaw accumulated gyro", "estimator attitude paper_c",
                 "estimator position paper_c", "localizer office tracking"):  # fmt: skip
        assert line in held, sorted(held)
        c = held[line]
        assert c["samples"] > 0
        assert 0.0 <= c["within_1_sigma"] <= c["within_2_sigma"] <= c["within_3_sigma"] <= 1.0
        assert c["nees_lower"] < c["dof"] < c["nees_upper"]
        assert c["nees_within_bounds"] == (c["nees_lower"] <= c["nees_mean"] <= c["nees_upper"])
    # the figures of all seeds pool the two halves
    assert payload["lines"]["all"]["yaw pair measured"]["samples"] == (
        payload["lines"]["fit"]["yaw pair measured"]["samples"] + held["yaw pair measured"]["samples"]
    )
    assert "yaw pair measured" in capsys.readouterr().out


def test_bench_consistency_needs_two_seeds() -> None:
    parser = argparse.ArgumentParser()
    consistency.add_arguments(parser)
    with pytest.raises(SystemExit):
        consistency.run(parser.parse_args(["--seeds", "1", "--suites", "yaw"]))
