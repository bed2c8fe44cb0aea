"""``capataz results``: docs/results.md and every marked figure of the README and docs, from the runs' JSON.

Reads ``make run``'s ``out/summary.json`` and each benchmark's ``out/bench/<name>.json`` (whichever exist;
at least one must), writes the page rendered by :mod:`services.tools.results_render` and fills the marked
spans (``<!-- fig:NAME -->...<!-- /fig -->``) of README.md and docs/*.md. A missing, unreadable or
malformed JSON is one line and exit 1. ``--check`` writes nothing and exits 1 when a file would change.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

from services.tools.results_render import FIGURES, ResultsError, figure_values, fill_spans, render_page, spans

logger = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[2]


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "results",
        help="write docs/results.md and the README's and docs' marked figures from out/summary.json and "
        "out/bench/*.json",
    )
    parser.add_argument("--summary", type=Path, default=Path("out/summary.json"), help="make run's summary")
    parser.add_argument(
        "--bench", type=Path, default=Path("out/bench"), help="folder of the benchmarks' JSON"
    )
    parser.add_argument(
        "--root", type=Path, default=ROOT, help="the checkout whose README.md and docs/ to fill"
    )
    parser.add_argument(
        "--docker", type=Path, default=Path("out"), help="folder of make test-docker's docker_e2e_*.json"
    )
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if a file would change")
    parser.set_defaults(handler=run)


def read_json(path: Path) -> dict[str, Any]:
    """One JSON object from ``path``; anything else is a :class:`ResultsError` naming the file."""
    try:
        payload = json.loads(path.read_text())
    except OSError as exc:
        raise ResultsError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise ResultsError(f"{path}: not JSON ({exc})") from None
    if not isinstance(payload, dict):
        raise ResultsError(f"{path}: not a JSON object")
    return payload


def read_sources(summary: Path, bench_dir: Path) -> tuple[dict[str, Any] | None, dict[str, dict[str, Any]]]:
    """make run's summary (None when absent) and every benchmark JSON in ``bench_dir`` by name."""
    run = read_json(summary) if summary.exists() else None
    bench = {p.stem: read_json(p) for p in sorted(bench_dir.glob("*.json"))} if bench_dir.is_dir() else {}
    if run is None and not bench:
        raise ResultsError(f"no {summary} and no {bench_dir}/*.json: run `make run` or `capataz bench` first")
    return run, bench


def marked_files(root: Path) -> list[Path]:
    """README.md and docs/*.md (except the generated page), the files whose marked spans are filled."""
    docs = [p for p in sorted((root / "docs").glob("*.md")) if p.name != "results.md"]
    return [p for p in (root / "README.md", *docs) if p.exists()]


def read_docker(folder: Path) -> dict[str, dict[str, Any]]:
    """``make test-docker``'s figures by run (``docker_e2e_v1``, ``docker_e2e_v2``), those that exist."""
    return {p.stem: read_json(p) for p in sorted(folder.glob("docker_e2e_*.json"))} if folder.is_dir() else {}


def updates(
    root: Path,
    run: dict[str, Any] | None,
    bench: dict[str, dict[str, Any]],
    docker: dict[str, dict[str, Any]] | None = None,
) -> dict[Path, str]:
    """Each file's new text (the page, and every marked file whose spans change)."""
    page = root / "docs" / "results.md"
    out = {page: render_page(run, bench, docker)}
    for path in marked_files(root):
        text = path.read_text()
        names = sorted({name for name, _ in spans(text)})
        if not names:
            continue
        if run is None:
            raise ResultsError(f"{path} quotes make run's figures but there is no summary: run `make run`")
        try:
            out[path] = fill_spans(text, figure_values(run, [n for n in names if n in FIGURES]))
        except ResultsError as exc:
            raise ResultsError(f"{path}: {exc}") from None
    return {p: t for p, t in out.items() if not p.exists() or p.read_text() != t}


def run(args: argparse.Namespace) -> int:
    try:
        run_summary, bench = read_sources(args.summary, args.bench)
        changed = updates(args.root, run_summary, bench, read_docker(args.docker))
    except ResultsError as exc:
        logger.error("capataz results: %s", exc)
        return 1
    if args.check:
        for path in changed:
            print(f"stale: {path}")
        if not changed:
            print("every figure is up to date")
        return 1 if changed else 0
    for path, text in changed.items():
        path.write_text(text)
        print(f"wrote {path}")
    if not changed:
        print("every figure is up to date")
    return 0
