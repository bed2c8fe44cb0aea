"""The agent run inside an emulated host: bad input is one line on stderr and exit code 2, before any
session is opened."""

from __future__ import annotations

import pytest

from services.tools.netns_agent import main

ENDPOINTS = ["--connect", "tcp/10.231.0.1:7447", "--listen", "tcp/10.231.0.1:0"]


@pytest.mark.parametrize(
    "argv",
    [
        [*ENDPOINTS, "yaw", "--count", "0"],
        [*ENDPOINTS, "serve", "k", "--size", "-1"],
        [*ENDPOINTS, "--timeout", "0", "sub", "k"],
    ],
)
def test_bad_numbers_are_one_line_and_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("netns_agent:")


def test_an_unknown_mode_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exc:
        main([*ENDPOINTS, "dance"])
    assert exc.value.code == 2
