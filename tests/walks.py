"""How an input walks through the project's modules: which modules control enters, in which order.

:func:`walk` runs a callable under ``sys.setprofile`` and records, for each Python function called, the
project module (a file under ``common/`` or ``services/``) it lives in. Consecutive calls within one module
are one entry; each call into a module after a call into another one is a new entry (a return is none).
Calls into code outside the project (numpy, zenoh, the standard library, the tests, the code dataclasses
generate) are not entries and do not interrupt a run of calls within one module. Numba's compiled functions
report their calls to the profiler too: they count.
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

import common

#: the checkout whose ``common`` is imported (the helper also measures another checkout on its PYTHONPATH)
ROOT = Path(common.__file__).resolve().parents[1]
PACKAGES = ("common", "services")


def _module_of(filename: str, cache: dict[str, str | None]) -> str | None:
    """``common/yaw/grid.py`` for a file of the project's packages, None for anything else."""
    if filename not in cache:
        try:
            relative = Path(filename).resolve().relative_to(ROOT)
        except ValueError:
            cache[filename] = None
        else:
            inside = relative.parts[0] in PACKAGES and relative.suffix == ".py"
            cache[filename] = relative.as_posix() if inside else None
    return cache[filename]


def walk(run: Callable[[], Any]) -> list[str]:
    """The modules ``run()`` enters, in order (consecutive calls within one module count as one entry)."""
    entries: list[str] = []
    cache: dict[str, str | None] = {}

    def profile(frame: FrameType, event: str, arg: object) -> None:
        if event != "call":
            return
        module = _module_of(frame.f_code.co_filename, cache)
        if module is not None and (not entries or entries[-1] != module):
            entries.append(module)

    previous = sys.getprofile()
    sys.setprofile(profile)
    try:
        run()
    finally:
        sys.setprofile(previous)
    return entries


def entries_per_module(entries: list[str]) -> dict[str, int]:
    """How many times each module was entered, most first."""
    return dict(Counter(entries).most_common())
