"""The text table of benchmark results."""

from __future__ import annotations

import pytest

from services.tools.report import print_table


def test_a_column_only_later_rows_have_is_printed(capsys: pytest.CaptureFixture[str]) -> None:
    """The cluster bench's ratios used to be written into the ``median_ms`` column (the table took its
    columns from the first row only); a ratio now has its own column."""
    print_table([{"config": "a", "median_ms": 12.5}, {"config": "gain none/time", "ratio": 1.25}], "t")
    header, _rule, first, second = capsys.readouterr().out.splitlines()[1:]
    assert header.split() == ["config", "median_ms", "ratio"]
    assert first.split() == ["a", "12.5"] and second.split()[-1] == "1.25"
    assert second.index("1.25") >= header.index("ratio")
