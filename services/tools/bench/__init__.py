"""``capataz bench <name>``: benchmarks that print a table and write ``out/bench/<name>.json``.

Each module in :data:`BENCH_MODULES` exposes ``NAME``, ``add_arguments(parser)`` and
``run(args) -> dict``; ``capataz bench all`` runs them in order with their defaults.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import ModuleType
from typing import Any

from services.runtime import progress
from services.tools.report import print_table, write_json

#: One line per benchmark.
BENCH_MODULES: tuple[str, ...] = (
    "services.tools.bench.localizer",
    "services.tools.bench.cluster",
    "services.tools.bench.yaw",
    "services.tools.bench.estimator",
    "services.tools.bench.record",
    "services.tools.bench.compression",
    "services.tools.bench.transport",
    "services.tools.bench.security",
    "services.tools.bench.ros2",
    "services.tools.bench.consistency",
    "services.tools.bench.dispatch",
    "services.tools.bench.allocator",
    "services.tools.bench.fft",
    "services.tools.bench.refine",
    "services.tools.bench.flow",
)


def _modules() -> list[ModuleType]:
    return [importlib.import_module(name) for name in BENCH_MODULES]


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("bench", help="run a benchmark; writes out/bench/<name>.json")
    parser.add_argument("--out", type=Path, default=Path("out/bench"), help="output folder")
    names = parser.add_subparsers(dest="bench", required=True, metavar="NAME")
    for module in _modules():
        sub = names.add_parser(module.NAME, help=(module.__doc__ or "").splitlines()[0])
        module.add_arguments(sub)
        sub.set_defaults(handler=_runner(module))
    every = names.add_parser("all", help="every benchmark with its defaults")
    every.set_defaults(handler=_run_all)


@contextmanager
def busy_loops(n: int) -> Iterator[None]:
    """``n`` processes spinning in pure Python for the duration (a busy host, for benches and tests)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def bench_metadata(name: str, command: str | None = None) -> dict[str, Any]:
    """When, at which commit and by which command (default: this process's ``capataz bench`` line) a
    measurement's JSON was written; ``capataz results`` prints it above the measurement's table."""
    from services.tools.run import git_commit

    argv = sys.argv[1:] if sys.argv[1:2] == ["bench"] and "all" not in sys.argv else ["bench", name]
    return {
        "time_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "git_commit": git_commit(Path(__file__).resolve().parents[3]),
        "command": command or " ".join(["capataz", *argv]),
    }


def _runner(module: ModuleType) -> Any:
    def handler(args: argparse.Namespace) -> int:
        with progress.bar(total=None, desc=f"bench {module.NAME}", unit="step"):
            result = module.run(args)
        # a suite may name its own file and payload (e.g. ``bench yaw --suite field`` -> yaw_field.json)
        name = result.pop("json_name", None) or result.pop("bench_name", module.NAME)
        payload = result.pop("json", result)
        if "table" not in payload and result.get("table"):
            payload = {**payload, "table": result["table"]}
        path = write_json(args.out / f"{name}.json", {"metadata": bench_metadata(module.NAME), **payload})
        print_table(result.get("table", []), title=f"bench {name}")
        print(f"wrote {path}")
        return 0

    return handler


def _run_all(args: argparse.Namespace) -> int:
    for module in _modules():
        sub = argparse.ArgumentParser()
        module.add_arguments(sub)
        sub_args = sub.parse_args([])
        sub_args.out = args.out
        _runner(module)(sub_args)
    return 0
