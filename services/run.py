"""``capataz run``: the embedded default, a simulated flight through every estimator, with a report in out/.

Each module in :data:`DEMO_MODULES` exposes ``run_demo(out_dir: Path) -> dict`` returning a flat
summary; ``capataz run`` runs them in order and writes ``out/summary.json``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
from pathlib import Path
from typing import Any

from services.report import write_json

logger = logging.getLogger(__name__)

#: One line per demo, in the order they run.
DEMO_MODULES: tuple[str, ...] = (
    "services.demo_cluster",
    "services.demo_localizer",
    "services.demo_estimator",
)


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("run", help="run the embedded default (a simulated flight) and report")
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder")
    parser.add_argument("--only", choices=[m.rsplit(".", 1)[-1] for m in DEMO_MODULES], help="one demo")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    summary: dict[str, Any] = {}
    for name in DEMO_MODULES:
        short = name.rsplit(".", 1)[-1]
        if args.only and args.only != short:
            continue
        logger.info("demo %s", short)
        summary[short] = importlib.import_module(name).run_demo(args.out)
    path = write_json(args.out / "summary.json", summary)
    print(f"wrote {path}")
    return 0
