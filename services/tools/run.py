"""``capataz run``: the embedded default, a simulated flight through every estimator, with a report in out/.

Each module in :data:`DEMO_MODULES` exposes ``run_demo(out_dir: Path) -> dict`` returning a flat
summary; ``capataz run`` runs them in order, with a progress bar, and writes ``out/summary.json``: one entry
per part plus ``metadata`` (time, version, git commit, seeds, settings). ``--only X`` runs one part and
merges it into an existing summary (the other parts' entries are kept).
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import logging
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from services.runtime import progress
from services.tools.report import write_json

logger = logging.getLogger(__name__)

#: One line per demo, in the order they run.
DEMO_MODULES: tuple[str, ...] = (
    "services.tools.demo_cluster",
    "services.tools.demo_localizer",
    "services.tools.demo_estimator",
)
#: A part started before the part named here, when both run: the localizer runs in this process, on one core,
#: while the estimator's two processes compile their kernels and work on the rest (both parts are offline and
#: deterministic: their figures do not change; make run 6 s shorter). The estimator part then only waits.
PRESTART: dict[str, str] = {"services.tools.demo_localizer": "services.tools.demo_estimator"}
#: the seeds of the embedded default (the demos' own defaults), recorded in the summary's metadata
SEEDS = {"demo_cluster": {"hover_flight": 0}, "demo_localizer": {"flight": 0, "filter": 1}}


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "run", help="run the embedded default (a simulated flight through every estimator) and report in out/"
    )
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder")
    parser.add_argument(
        "--only",
        choices=[m.rsplit(".", 1)[-1] for m in DEMO_MODULES],
        help="run one part and merge it into OUT/summary.json (default: every part)",
    )
    parser.set_defaults(handler=run)


def git_commit(root: Path) -> str | None:
    """The checkout's commit (with ``+dirty`` when it has changes), or None outside a git checkout."""
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if commit.returncode != 0:
        return None
    return commit.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def metadata(args: argparse.Namespace, parts: list[str], durations_s: dict[str, float]) -> dict[str, Any]:
    from services.tools.cli import version

    return {
        "time_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "version": version(),
        "git_commit": git_commit(Path(__file__).resolve().parents[2]),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "argv": sys.argv[1:],
        "parts_run": parts,
        "durations_s": durations_s,
        "seeds": {p: SEEDS.get(p, {}) for p in parts},
        "settings": {"out": str(args.out), "only": args.only},
    }


def _previous(path: Path) -> dict[str, Any]:
    """The summary already in ``path`` (for ``--only``); an unreadable one is replaced, with a warning."""
    if not path.exists():
        return {}
    try:
        previous = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        logger.warning("%s is not a summary (%s): replacing it", path, exc)
        return {}
    return previous if isinstance(previous, dict) else {}


def run(args: argparse.Namespace) -> int:
    # a folder that cannot be written is one line before any demo runs (not after the first one, 10 s in)
    args.out.mkdir(parents=True, exist_ok=True)
    names = [m for m in DEMO_MODULES if not args.only or m.rsplit(".", 1)[-1] == args.only]
    path = args.out / "summary.json"
    summary = _previous(path) if args.only else {}
    history = summary.pop("metadata", {}) if args.only else {}
    durations: dict[str, float] = dict(history.get("durations_s", {}))
    started: dict[str, Any] = {}
    try:
        with progress.bar(total=len(names), desc="capataz run", unit="part") as bar:
            for name in names:
                short = name.rsplit(".", 1)[-1]
                bar.note(short)
                logger.info("demo %s", short)
                t0 = time.monotonic()
                ahead = PRESTART.get(name)
                if ahead in names:
                    started[ahead] = importlib.import_module(ahead).start(args.out)
                module = importlib.import_module(name)
                if name in started:
                    summary[short] = module.run_demo(args.out, started.pop(name))
                else:
                    summary[short] = module.run_demo(args.out)
                durations[short] = round(time.monotonic() - t0, 1)
                bar.update()
    finally:
        for work in started.values():  # a part failed before the one started ahead ran
            work.cancel()
    parts = [name.rsplit(".", 1)[-1] for name in names]
    meta = metadata(args, parts, durations)
    if args.only:
        meta["seeds"] = {**history.get("seeds", {}), **meta["seeds"]}
    write_json(path, {"metadata": meta, **summary})
    print(f"wrote {path} ({', '.join(f'{p} {durations[p]:.0f} s' for p in parts)})")
    return 0
