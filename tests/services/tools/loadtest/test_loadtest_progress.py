"""The load test's progress line: redrawn in place on a terminal, plain lines into a file (regression: a
report redirected to a file was full of carriage returns)."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

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


def test_the_lost_frames_panel_says_no_frame_was_lost_instead_of_staying_empty(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 28: the load-test figure had an empty panel when nothing was lost."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from services.tools.loadtest.report import plot

    captured: list[list[str]] = []
    real_close = plt.close

    def keep_texts(fig: Figure) -> None:
        captured.append([t.get_text() for ax in fig.axes for t in ax.texts])
        real_close(fig)

    monkeypatch.setattr(plt, "close", keep_texts)
    report = {"timeline": {"uav0": [(0.0, 5.0), (0.05, 6.0)], "uav1": [(0.0, 7.0)]}, "cpu_s": {"m": 1.0}}
    assert plot(report, tmp_path / "a.png") == tmp_path / "a.png"
    plot({"timeline": {"uav0": [(0.0, 5.0), (0.05, None)]}, "cpu_s": {}}, tmp_path / "b.png")
    assert any("no frame lost\n(3 frames, 2 streams)" in t for t in captured[0])
    assert not any("no frame lost" in t for t in captured[1])
