"""The results page and the figures the README and docs quote, rendered from the JSON the runs write.

Pure: dictionaries in (``make run``'s ``out/summary.json``, each benchmark's ``out/bench/<name>.json`` by
name, ``make test-docker``'s ``out/docker_e2e_*.json`` by run), text out. ``capataz results``
(:mod:`services.tools.results`) reads the files and writes what this renders.

A figure quoted in Markdown sits in a marked span that only the generator fills, so each figure has one home
(its JSON) and a test can compare every span with a fresh run::

    <!-- fig:run.yaw_rmse_deg -->0.146 deg<!-- /fig -->

Figures that depend on the machine (speed, wall time, CPU) are rendered with :data:`MACHINE_LABEL`. The yaw's
accumulated mean error is paper A's eq. 8.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

#: the label every machine-dependent figure carries, in a span and on the page
MACHINE_LABEL = "(machine-dependent)"
#: a marked span: ``<!-- fig:NAME -->content<!-- /fig -->``
SPAN = re.compile(r"<!-- fig:([\w.]+) -->(.*?)<!-- /fig -->", re.S)
#: bench table columns whose values depend on the machine (speed, time, CPU)
MACHINE_COLUMN = re.compile(
    r"(^|_)(ms|us|s|fps|cpu|core|hz|counts|speed|speedup|speed_up|time|wall|steal|load)(_|$)|per_s", re.I
)


class ResultsError(ValueError):
    """A source that is missing or is not what the renderer needs (one line for the user)."""


@dataclass(frozen=True)
class Figure:
    """One quoted figure: ``name`` (``<source>.<what>_<unit>``), where it is in its source's JSON
    (``path``), how it is printed (``fmt`` of ``value * scale``, with its unit) and whether it depends on
    the machine (then it is labelled, and a fresh run is not expected to reproduce it)."""

    name: str
    path: tuple[str | int, ...]
    fmt: str
    scale: float = 1.0
    machine: bool = False
    what: str = ""


#: name (after ``run.``), path in out/summary.json, format with unit, what it is
_RUN_ROWS: tuple[tuple[str, str, str, str], ...] = (
    ("yaw_frames", "demo_cluster.frames", "{:.0f}", "hover frames through the cluster"),
    ("yaw_rmse_deg", "demo_cluster.rms_deg", "{:.3f} deg", "yaw RMSE through the cluster"),
    ("yaw_max_ame_deg", "demo_cluster.max_ame_deg", "{:.3f} deg", "yaw max accumulated mean error (eq. 8)"),
    ("yaw_final_deg", "demo_cluster.final_deg", "{:+.3f} deg", "yaw error on the last frame"),
    ("yaw_evo_deg", "demo_cluster.tum.ape_rotation_rmse_deg", "{:.3f} deg", "evo APE of yaw.tum"),
    ("loc_frames", "demo_localizer.frames", "{:.0f}", "office frames through the localizer"),
    ("loc_guess_cm", "demo_localizer.guess_position_error_cm", "{:.0f} cm", "localizer's start guess off"),
    ("loc_guess_yaw_deg", "demo_localizer.guess_yaw_error_deg", "{:.1f} deg", "start guess's yaw off"),
    ("loc_position_rmse_cm", "demo_localizer.position_rmse_cm", "{:.2f} cm", "localizer position RMSE"),
    ("loc_yaw_rmse_deg", "demo_localizer.yaw_rmse_deg", "{:.3f} deg", "localizer yaw RMSE"),
    ("loc_evo_cm", "demo_localizer.tum.ape_translation_rmse_m", "{:.2f} cm", "evo APE of pose_pf.tum"),
    ("est_path_m", "demo_estimator.path_length_m", "{:.2f} m", "paper C's flight (b), path length"),
    ("est_ate_cm", "demo_estimator.ate_rmse_cm", "{:.2f} cm", "estimator VO ATE RMSE, rectified"),
    ("est_rpe_pct", "demo_estimator.rpe_pct", "{:.3f} %/m", "VO RPE (1 m), rectified"),
    ("est_roll_deg", "demo_estimator.att_rmse_deg_roll_pitch_yaw.0", "{:.3f} deg", "roll RMSE"),
    ("est_pitch_deg", "demo_estimator.att_rmse_deg_roll_pitch_yaw.1", "{:.3f} deg", "pitch RMSE"),
    ("est_yaw_deg", "demo_estimator.att_rmse_deg_roll_pitch_yaw.2", "{:.3f} deg", "filter yaw RMSE"),
    ("est_alt_cm", "demo_estimator.alt_rmse_cm", "{:.2f} cm", "altitude RMSE"),
    (
        "est_attitude_evo_deg",
        "demo_estimator.tum.attitude.ape_rotation_rmse_deg",
        "{:.3f} deg",
        "evo APE of attitude.tum",
    ),
    (
        "est_pose_vo_evo_cm",
        "demo_estimator.tum.pose_vo.ape_translation_rmse_m",
        "{:.2f} cm",
        "evo APE of pose_vo.tum",
    ),
    ("yaw_evo_poses", "demo_cluster.tum.poses", "{:.0f}", "poses in yaw.tum"),
    ("est_attitude_evo_poses", "demo_estimator.tum.attitude.poses", "{:.0f}", "poses in attitude.tum"),
    ("est_pose_vo_evo_poses", "demo_estimator.tum.pose_vo.poses", "{:.0f}", "poses in pose_vo.tum"),
    (
        "est_pose_vo_evo_deg",
        "demo_estimator.tum.pose_vo.ape_rotation_rmse_deg",
        "{:.3f} deg",
        "evo APE of pose_vo.tum, rotation",
    ),
    ("loc_evo_poses", "demo_localizer.tum.poses", "{:.0f}", "poses in pose_pf.tum"),
    (
        "loc_evo_deg",
        "demo_localizer.tum.ape_rotation_rmse_deg",
        "{:.2f} deg",
        "evo APE of pose_pf.tum, rotation",
    ),
    (
        "loc_settle_frames",
        "demo_localizer.settle_frames",
        "{:.0f}",
        "localizer settling frames (not in RMSE)",
    ),
    ("cluster_s", "metadata.durations_s.demo_cluster", "{:.0f} s", "make run: cluster part, wall time"),
    ("localizer_s", "metadata.durations_s.demo_localizer", "{:.0f} s", "make run: localizer part, wall time"),
    ("estimator_s", "metadata.durations_s.demo_estimator", "{:.0f} s", "make run: estimator part, wall time"),
    ("cluster_fps", "demo_cluster.fps", "{:.0f} fps", "cluster frames per second"),
    ("cluster_ms", "demo_cluster.ms_per_frame_median", "{:.1f} ms", "cluster ms per frame (median)"),
    (
        "in_process_ms",
        "demo_cluster.in_process_ms_per_frame_median",
        "{:.2f} ms",
        "in-process core ms per frame (median)",
    ),
)
#: figures whose JSON unit is not the one quoted (metres quoted in centimetres)
_SCALE: dict[str, float] = {"loc_evo_cm": 100.0, "est_pose_vo_evo_cm": 100.0}
#: figures that depend on the machine (speed, wall time): labelled, never compared with a fresh run
_MACHINE = frozenset(
    {"cluster_s", "localizer_s", "estimator_s", "cluster_fps", "cluster_ms", "in_process_ms"}
)


def _path(dotted: str) -> tuple[str | int, ...]:
    return tuple(int(k) if k.isdigit() else k for k in dotted.split("."))


#: every figure of ``make run`` the README and docs may quote (from out/summary.json)
RUN_FIGURES: tuple[Figure, ...] = tuple(
    Figure(f"run.{name}", _path(path), fmt, _SCALE.get(name, 1.0), name in _MACHINE, what)
    for name, path, fmt, what in _RUN_ROWS
)
FIGURES: dict[str, Figure] = {f.name: f for f in RUN_FIGURES}


def lookup(source: Any, path: Sequence[str | int]) -> Any:
    """The value at ``path`` in a JSON document; a missing key is a :class:`ResultsError` naming it."""
    value = source
    for key in path:
        try:
            value = value[key]
        except (KeyError, IndexError, TypeError):
            raise ResultsError(f"no {'.'.join(map(str, path))} (missing at {key!r})") from None
    return value


def render_figure(figure: Figure, source: Mapping[str, Any]) -> str:
    """The text of one figure as the README and docs quote it (with its label when machine-dependent)."""
    value = lookup(source, figure.path)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ResultsError(f"{'.'.join(map(str, figure.path))} is not a finite number: {value!r}")
    text = figure.fmt.format(value * figure.scale)
    return f"{text} {MACHINE_LABEL}" if figure.machine else text


def figure_values(run: Mapping[str, Any], names: Sequence[str] | None = None) -> dict[str, str]:
    """Every figure of :data:`FIGURES` (or those ``names``) rendered from ``make run``'s summary."""
    chosen = FIGURES.values() if names is None else [FIGURES[n] for n in names]
    return {f.name: render_figure(f, run) for f in chosen}


def spans(text: str) -> list[tuple[str, str]]:
    """The marked spans of a Markdown text: (figure name, quoted content), in order."""
    return [(m.group(1), m.group(2)) for m in SPAN.finditer(text)]


def fill_spans(text: str, values: Mapping[str, str]) -> str:
    """``text`` with every marked span's content replaced by its figure's value; an unknown name is a
    :class:`ResultsError` (a span nobody generates would go stale)."""

    def replace(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in values:
            raise ResultsError(f"unknown figure {name!r} in a marked span")
        return f"<!-- fig:{name} -->{values[name]}<!-- /fig -->"

    return SPAN.sub(replace, text)


def _stamp(meta: Mapping[str, Any] | None) -> str:
    if not isinstance(meta, Mapping):
        return "date and commit not recorded"
    return f"{meta.get('time_utc', 'date not recorded')}, commit {meta.get('git_commit') or 'not recorded'}"


def _cell(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return "-" if value is None else str(value).lower()
    if isinstance(value, float):
        return "-" if not math.isfinite(value) else (f"{value:.4g}" if abs(value) < 1e5 else f"{value:.0f}")
    if isinstance(value, (list, tuple)):
        return ", ".join(_cell(v) for v in value)
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Rows of dicts as a Markdown table; machine-dependent columns (speed, time, CPU) end in ``*``."""
    columns = list(dict.fromkeys(c for row in rows for c in row))
    head = [f"{c} *" if MACHINE_COLUMN.search(c) else c for c in columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_cell(row.get(c)) for c in columns) + " |" for row in rows]
    return "\n".join(lines)


def _section(title: str, intro: str, rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """A page section: its heading, one paragraph, its table."""
    return [f"## {title}", "", intro, "", markdown_table(rows), ""]


def _run_section(run: Mapping[str, Any]) -> list[str]:
    meta = run.get("metadata")
    parts = {str(f.path[0]) for f in RUN_FIGURES} - {"metadata"}
    if not parts & set(run):
        raise ResultsError(f"the summary has none of make run's parts ({', '.join(sorted(parts))})")
    # a part not run (``capataz run --only``) is left out; a part that was run lacks no figure
    rows = [
        {"figure": f.what, "value": render_figure(f, run), "name": f"`{f.name}`"}
        for f in RUN_FIGURES
        if f.path[0] in run and (f.path[0] != "metadata" or f.path[2] in run)
    ]
    return _section(
        "The embedded default (`make run`)",
        f"`make run` (`capataz run`), {_stamp(meta)}: out/summary.json. Paper A's hover through the local"
        " cluster (whose yaw equals the in-process core's), the localizer over the built-in office and"
        " the estimator over paper C's flight (b); deterministic by seed except the figures marked"
        f" {MACHINE_LABEL}.",
        rows,
    )


def _bench_section(name: str, payload: Mapping[str, Any]) -> list[str]:
    meta = payload.get("metadata")
    command = meta.get("command") if isinstance(meta, Mapping) else None
    lines = [f"## `bench {name}`", ""]
    lines.append(f"`{command or f'capataz bench {name}'}`, {_stamp(meta)}: out/bench/{name}.json.")
    for key in ("note", "settings"):
        if isinstance(payload.get(key), (str, Mapping)):
            value = payload[key]
            text = value if isinstance(value, str) else ", ".join(f"{k} {_cell(v)}" for k, v in value.items())
            lines.append(f"{key.capitalize()}: {text}.")
    table = payload.get("table")
    if isinstance(table, list) and table and all(isinstance(r, Mapping) for r in table):
        lines += ["", markdown_table(table)]
    else:
        scalars = {
            k: v for k, v in payload.items() if isinstance(v, (int, float)) and not isinstance(v, bool)
        }
        if not scalars:
            raise ResultsError(f"bench {name}: no table and no figures in its JSON")
        lines += ["", markdown_table([{"figure": k, "value": v} for k, v in scalars.items()])]
    return [*lines, ""]


def _flat(payload: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Scalar leaves of a JSON object by dotted key (lists of scalars kept whole; metadata left out)."""
    out: dict[str, Any] = {}
    for key, value in payload.items():
        name = f"{prefix}{key}"
        if key == "metadata" and not prefix:
            continue
        if isinstance(value, Mapping):
            out.update(_flat(value, f"{name}."))
        elif not isinstance(value, list) or all(not isinstance(v, (Mapping, list)) for v in value):
            out[name] = value
    return out


def _docker_section(docker: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """``make test-docker``'s figures, one column per run (out/docker_e2e_v1.json, _v2.json)."""
    names = sorted(docker)
    flat = {name: _flat(docker[name]) for name in names}
    keys = list(dict.fromkeys(k for name in names for k in flat[name]))
    rows = [
        {"figure": f"{k} *" if MACHINE_COLUMN.search(k.rsplit(".", 1)[0]) else k}
        | {name: flat[name].get(k) for name in names}
        for k in keys
    ]
    stamps = "; ".join(f"{name}: {_stamp(docker[name].get('metadata'))}" for name in names)
    return _section(
        "The compose deployment (`make test-docker`)",
        f"`make test-docker` on a real Docker engine, out/<run>.json ({stamps}). Rows marked `*` are times"
        " and rates of the host that ran them.",
        rows,
    )


def render_page(
    run: Mapping[str, Any] | None,
    bench: Mapping[str, Mapping[str, Any]],
    docker: Mapping[str, Mapping[str, Any]] | None = None,
) -> str:
    """docs/results.md: ``make run``'s figures, one table per benchmark JSON (in name order), then the
    compose deployment's runs."""
    if run is None and not bench and not docker:
        raise ResultsError("nothing to render: no summary and no benchmark JSON")
    lines = [
        "# Results",
        "",
        "<!-- generated by `capataz results` from out/summary.json and out/bench/*.json: do not edit -->",
        "",
        "Each table names the command that measured it and the date and commit it ran at. Accuracy figures"
        " are deterministic for a seed; columns marked `*` and figures marked"
        f" {MACHINE_LABEL} are speeds, times or CPU of the host that ran them. `make results` regenerates"
        " this page and every marked figure in the README and docs.",
        "",
    ]
    if run is not None:
        lines += _run_section(run)
    for name in sorted(bench):
        lines += _bench_section(name, bench[name])
    if docker:
        lines += _docker_section(docker)
    return "\n".join(lines).rstrip("\n") + "\n"
