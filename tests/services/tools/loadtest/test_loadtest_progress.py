"""The load test's progress line: redrawn in place on a terminal, plain lines into a file (regression: a
report redirected to a file was full of carriage returns)."""

from __future__ import annotations

import io

from services.tools.loadtest.runner import _progress, progress_interval_s


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_file_gets_plain_lines_every_ten_seconds_and_a_terminal_one_redrawn_line() -> None:
    into_file, terminal = io.StringIO(), Terminal()
    for out in (into_file, terminal):
        _progress(0.0, {}, out)
        _progress(0.0, {}, out)
    assert "\r" not in into_file.getvalue() and into_file.getvalue().count("\n") == 2
    assert terminal.getvalue().count("\r") == 2 and "\n" not in terminal.getvalue()
    assert progress_interval_s(into_file) == 10.0 and progress_interval_s(terminal) == 1.0
