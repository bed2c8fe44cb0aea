"""Run the test suite on a host whose cores are busy: ``python -m tests.under_load [--busy N] [pytest args]``.

Starts N busy-loop processes (default: one per core, at least 2) that spin in pure Python for the whole
run, runs pytest in a child process, stops the busy processes (by their own ids) and exits with pytest's
code. The suite must pass like this: a test that only passes on an idle host measures the host, not the code.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import subprocess
import sys
import time


def _spin(stop_at: float) -> None:
    x = 0
    while time.monotonic() < stop_at:
        x = (x * 1103515245 + 12345) % 2147483648  # pure Python: holds a core


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--busy", type=int, default=max(2, os.cpu_count() or 2), help="busy-loop processes")
    parser.add_argument(
        "--limit-s", type=float, default=3600.0, help="busy loops end by themselves after this"
    )
    args, pytest_args = parser.parse_known_args(argv)
    stop_at = time.monotonic() + args.limit_s
    spinners = [multiprocessing.Process(target=_spin, args=(stop_at,), daemon=True) for _ in range(args.busy)]
    for spinner in spinners:
        spinner.start()
    print(
        f"under load: {args.busy} busy-loop processes {[s.pid for s in spinners]} on {os.cpu_count()} cores"
    )
    try:
        return subprocess.call([sys.executable, "-m", "pytest", *pytest_args])
    finally:
        for spinner in spinners:
            spinner.terminate()
            spinner.join(5.0)


if __name__ == "__main__":
    sys.exit(main())
