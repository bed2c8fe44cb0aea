"""Progress bars with an ETA for long command-line steps (``run``, ``bench``, ``loadtest``).

    with progress.bar(total=2041, desc="yaw cluster", unit="frame") as bar:
        for ... :
            bar.update()              # or bar.set(done) from a polling loop
            bar.note(f"{fps:.1f} fps")

A bar is drawn (with tqdm, on stderr) only when stderr is a terminal, ``CI`` is not set and ``--quiet`` was
not given (:func:`configure`); otherwise it is silent and costs nothing. Log lines printed while a bar is
shown go above it.
"""

from __future__ import annotations

import os
import shutil
import sys
import threading
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any, TypeVar

T = TypeVar("T")

_state = {"quiet": False}


def configure(quiet: bool) -> None:
    """Set by the ``capataz`` entry point from ``--quiet``."""
    _state["quiet"] = quiet


def quiet() -> bool:
    """``--quiet`` was given: no bars and no periodic progress lines either."""
    return _state["quiet"]


def enabled() -> bool:
    """Bars are drawn: not quiet, stderr is a terminal, and not under CI."""
    if _state["quiet"] or os.environ.get("CI", "").strip().lower() not in {"", "0", "false"}:
        return False
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


class Bar:
    """One bar; a no-op when bars are disabled."""

    def __init__(self, impl: Any | None) -> None:
        self._impl = impl

    @property
    def shown(self) -> bool:
        return self._impl is not None

    def update(self, n: float = 1) -> None:
        if self._impl is not None:
            self._impl.update(n)

    def set(self, done: float) -> None:
        """Move to ``done`` (for loops that poll a count rather than step through it)."""
        if self._impl is not None and done != self._impl.n:
            self._impl.update(done - self._impl.n)

    def track(self, items: Iterable[T]) -> Iterator[T]:
        """``items``, counting each one as it is consumed."""
        for item in items:
            yield item
            self.update()

    def note(self, text: str) -> None:
        """Short live figures after the bar (``12.3 fps, yaw +0.012 rad``)."""
        if self._impl is not None:
            self._impl.set_postfix_str(text, refresh=False)


@contextmanager
def bar(total: float | None, desc: str, unit: str = "it") -> Iterator[Bar]:
    """A progress bar with rate and ETA, closed on exit (also on an exception).

    The bar is redrawn every second even without updates, so that a long step shows its elapsed time (a step
    whose length is unknown: ``total=None``).
    """
    if not enabled():
        yield Bar(None)
        return
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    # a terminal that reports no size (0x0, e.g. under `script`) would hide the bar: assume 100x24 then
    columns, rows = shutil.get_terminal_size((100, 24))
    with ExitStack() as stack:
        stack.enter_context(logging_redirect_tqdm())
        impl = stack.enter_context(
            tqdm(total=total, desc=desc, unit=unit, ncols=columns, nrows=rows, leave=True, file=sys.stderr)
        )
        done = threading.Event()
        ticker = threading.Thread(target=_tick, args=(impl, done), name="progress", daemon=True)
        ticker.start()
        stack.callback(ticker.join)
        stack.callback(done.set)
        yield Bar(impl)


def _tick(impl: Any, done: threading.Event) -> None:
    while not done.wait(1.0):
        impl.refresh()
