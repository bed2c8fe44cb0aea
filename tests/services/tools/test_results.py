"""``capataz results``: the page and the marked figures rendered from hand-made JSON; bad JSON is one line."""

from __future__ import annotations

import argparse
import copy
import json
import logging
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.tools import results
from services.tools.results_render import (
    FIGURES,
    MACHINE_LABEL,
    ResultsError,
    figure_values,
    fill_spans,
    markdown_table,
    render_page,
    spans,
)

META = {"time_utc": "2026-01-02T03:04:05+00:00", "git_commit": "abc1234", "durations_s": {}}


def hand_made_summary() -> dict[str, Any]:
    """A summary shaped like ``make run``'s with round numbers."""
    return {
        "metadata": {**META, "durations_s": {"demo_cluster": 40.4, "demo_localizer": 9.6,
                                              "demo_estimator": 20.0}},
        "demo_cluster": {
            "frames": 2041, "rms_deg": 0.14592, "max_ame_deg": 0.1375, "final_deg": 0.19899,
            "fps": 61.8, "ms_per_frame_median": 11.82, "in_process_ms_per_frame_median": 1.831,
            "tum": {"ape_rotation_rmse_deg": 0.14592, "poses": 2041},
        },
        "demo_localizer": {
            "frames": 300, "guess_position_error_cm": 35.3, "guess_yaw_error_deg": 4.61,
            "position_rmse_cm": 1.9498, "yaw_rmse_deg": 0.2057, "settle_frames": 75,
            "tum": {"ape_translation_rmse_m": 0.075524, "ape_rotation_rmse_deg": 1.2144, "poses": 300},
        },
        "demo_estimator": {
            "path_length_m": 13.8316, "ate_rmse_cm": 0.36925, "ate_rmse_cm_unrectified": 0.7447,
            "rpe_pct": 0.34213, "att_rmse_deg_roll_pitch_yaw": [0.02684, 0.02918, 0.2156],
            "alt_rmse_cm": 0.6852,
            "tum": {"attitude": {"ape_rotation_rmse_deg": 0.21922, "poses": 20001},
                    "pose_vo": {"ape_translation_rmse_m": 0.0076141, "ape_rotation_rmse_deg": 0.2258,
                                "poses": 921}},
        },
    }  # fmt: skip


def test_figures_render_at_their_printed_precision_with_units_and_labels() -> None:
    values = figure_values(hand_made_summary())
    assert set(values) == set(FIGURES)
    assert values["run.yaw_rmse_deg"] == "0.146 deg"
    assert values["run.yaw_final_deg"] == "+0.199 deg"
    assert values["run.yaw_frames"] == "2041"
    assert values["run.loc_evo_cm"] == "7.55 cm"  # metres in the JSON, centimetres quoted
    assert values["run.est_pitch_deg"] == "0.029 deg"  # the second of roll, pitch, yaw
    assert values["run.est_pose_vo_evo_cm"] == "0.76 cm"
    assert values["run.cluster_fps"] == f"62 fps {MACHINE_LABEL}"
    assert values["run.cluster_s"] == f"40 s {MACHINE_LABEL}"
    machine = {n for n, v in values.items() if v.endswith(MACHINE_LABEL)}
    assert machine == {f.name for f in FIGURES.values() if f.machine}


def test_the_page_from_hand_made_json() -> None:
    bench: dict[str, dict[str, Any]] = {
        "yaw": {
            "metadata": {**META, "command": "capataz bench yaw --frames 300"},
            "note": "one core",
            "settings": {"frames": 300, "images": "simulated"},
            "table": [
                {"method": "core", "ms_per_frame": 1.16, "max_ame_deg": 0.151},
                {"method": "paper", "ms_per_frame": 2.72, "max_ame_deg": 0.624, "note": "a|b"},
            ],
        },
        "record": {"mb_per_minute": 443.0, "frames": 200, "ok": True},  # no table, no metadata
    }
    page = render_page(hand_made_summary(), bench)
    assert page.startswith("# Results\n")
    assert "`make run` (`capataz run`), 2026-01-02T03:04:05+00:00, commit abc1234: out/summary.json." in page
    assert "| yaw RMSE through the cluster | 0.146 deg | `run.yaw_rmse_deg` |" in page
    assert f"| cluster frames per second | 62 fps {MACHINE_LABEL} | `run.cluster_fps` |" in page
    # benchmarks in name order, each with its command, date and commit
    assert page.index("## `bench record`") < page.index("## `bench yaw`")
    assert (
        "`capataz bench yaw --frames 300`, 2026-01-02T03:04:05+00:00, commit abc1234: out/bench/yaw.json."
        in page
    )
    assert "`capataz bench record`, date and commit not recorded: out/bench/record.json." in page
    assert "Note: one core.\nSettings: frames 300, images simulated." in page
    yaw_table = (
        "| method | ms_per_frame * | max_ame_deg | note |\n|---|---|---|---|\n"
        "| core | 1.16 | 0.151 | - |\n| paper | 2.72 | 0.624 | a\\|b |"
    )
    assert yaw_table in page
    assert "| figure | value |\n|---|---|---|\n" not in page
    assert "| mb_per_minute | 443 |\n| frames | 200 |" in page  # scalars; the bool is not a figure
    assert page.endswith("|\n")


def test_machine_columns_are_marked() -> None:
    table = markdown_table(
        [{"fps": 1.0, "cpu_s": 2.0, "ate_cm": 0.3, "speedup": 2.0, "steps": 3, "core_share": 1}]
    )
    assert table.splitlines()[0] == "| fps * | cpu_s * | ate_cm | speedup * | steps | core_share * |"


def test_spans_are_filled_and_an_unknown_or_missing_figure_is_refused() -> None:
    text = (
        "yaw <!-- fig:run.yaw_rmse_deg -->0.138 deg<!-- /fig -->, <!-- fig:run.yaw_frames -->1<!-- /fig -->."
    )
    filled = fill_spans(text, figure_values(hand_made_summary()))
    assert filled == text.replace("0.138", "0.146").replace("-->1<", "-->2041<")
    assert spans(filled) == [("run.yaw_rmse_deg", "0.146 deg"), ("run.yaw_frames", "2041")]
    with pytest.raises(ResultsError, match=r"unknown figure 'run\.nope'"):
        fill_spans("<!-- fig:run.nope -->1<!-- /fig -->", {})
    summary = hand_made_summary()
    del summary["demo_localizer"]["tum"]
    with pytest.raises(ResultsError, match=r"no demo_localizer\.tum\.ape_translation_rmse_m"):
        figure_values(summary, ["run.loc_evo_cm"])
    summary["demo_cluster"]["rms_deg"] = None  # NaN is written as null
    with pytest.raises(ResultsError, match="not a finite number"):
        figure_values(summary, ["run.yaw_rmse_deg"])


@given(st.floats(min_value=-1e3, max_value=1e3, allow_nan=False), st.text(alphabet="ab .\n", max_size=20))
def test_filling_is_idempotent_and_leaves_the_text_around_the_spans(value: float, around: str) -> None:
    summary = hand_made_summary()
    summary["demo_cluster"]["rms_deg"] = value
    values = figure_values(summary, ["run.yaw_rmse_deg"])
    text = f"{around}<!-- fig:run.yaw_rmse_deg -->old<!-- /fig -->{around}"
    once = fill_spans(text, values)
    assert fill_spans(once, values) == once
    assert once == f"{around}<!-- fig:run.yaw_rmse_deg -->{value:.3f} deg<!-- /fig -->{around}"


def _args(tmp_path: Path, **kw: Any) -> argparse.Namespace:
    root = tmp_path / "repo"
    (root / "docs").mkdir(parents=True, exist_ok=True)
    base = {
        "summary": tmp_path / "summary.json",
        "bench": tmp_path / "bench",
        "docker": tmp_path,
        "root": root,
        "check": False,
    }
    return argparse.Namespace(**{**base, **kw})


def test_the_command_writes_the_page_and_fills_the_readme_and_docs(tmp_path: Path) -> None:
    args = _args(tmp_path)
    args.summary.write_text(json.dumps(hand_made_summary()))
    (args.root / "README.md").write_text("x <!-- fig:run.loc_evo_cm -->8.71 cm<!-- /fig -->\n")
    (args.root / "docs" / "run.md").write_text("no figures\n")
    assert results.run(args) == 0
    assert (args.root / "README.md").read_text() == "x <!-- fig:run.loc_evo_cm -->7.55 cm<!-- /fig -->\n"
    assert (args.root / "docs" / "results.md").read_text() == render_page(hand_made_summary(), {})
    assert (args.root / "docs" / "run.md").read_text() == "no figures\n"
    assert results.run(_args(tmp_path, check=True)) == 0  # up to date
    stale = copy.deepcopy(hand_made_summary())
    stale["demo_localizer"]["tum"]["ape_translation_rmse_m"] = 0.0871
    args.summary.write_text(json.dumps(stale))
    assert results.run(_args(tmp_path, check=True)) == 1
    assert "7.55 cm" in (args.root / "README.md").read_text()  # --check writes nothing


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no {summary} and no {bench}/*.json"),
        ("{not json", "{summary}: not JSON"),
        ("[1, 2]", "{summary}: not a JSON object"),
        ('{"metadata": {}}', "the summary has none of make run's parts"),
        ('{"demo_cluster": {"frames": 3}}', "no demo_cluster.rms_deg"),
    ],
)
def test_a_missing_or_malformed_json_is_one_line_and_exit_1(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, content: str | None, message: str
) -> None:
    args = _args(tmp_path)
    (args.root / "README.md").write_text("<!-- fig:run.yaw_rmse_deg -->1<!-- /fig -->\n")
    if content is not None:
        args.summary.write_text(content)
    with caplog.at_level(logging.ERROR):
        assert results.run(args) == 1
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "\n" not in errors[0]
    assert message.format(summary=args.summary, bench=args.bench) in errors[0]
    assert not (args.root / "docs" / "results.md").exists()


def test_a_malformed_bench_json_names_its_file(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    args = _args(tmp_path)
    args.bench.mkdir()
    (args.bench / "yaw.json").write_text('{"table": "not rows"}')
    with caplog.at_level(logging.ERROR):
        assert results.run(args) == 1
    assert "bench yaw: no table and no figures in its JSON" in caplog.text


def test_the_compose_deployments_runs_side_by_side() -> None:
    docker: dict[str, dict[str, Any]] = {
        "docker_e2e_v1": {
            "compose": "docker-compose 1.29.2",
            "rates_hz": {"yaw": 19.99},
            "yaw_rms_error_deg": 0.12,
        },
        "docker_e2e_v2": {"compose": "docker compose 2.26", "status_not_ok": [], "metadata": META},
    }
    page = render_page(None, {}, docker)
    assert (
        "docker_e2e_v1: date and commit not recorded; "
        "docker_e2e_v2: 2026-01-02T03:04:05+00:00, commit abc1234" in page
    )
    assert (
        "| figure | docker_e2e_v1 | docker_e2e_v2 |\n|---|---|---|\n"
        "| compose | docker-compose 1.29.2 | docker compose 2.26 |\n"
        "| rates_hz.yaw * | 19.99 | - |\n| yaw_rms_error_deg | 0.12 | - |\n| status_not_ok | - |  |"
    ) in page
    with pytest.raises(ResultsError, match="nothing to render"):
        render_page(None, {}, {})
