"""``capataz ros2`` without the ros2 extra: one line saying how to install it, exit 1, no traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from services.ros2 import MISSING_EXTRA

ROOT = Path(__file__).resolve().parents[3]
# rclpy made unimportable in the child, as on an install without the extra
WITHOUT_EXTRA = (
    "import sys; sys.modules['rclpy'] = None\n"
    "from services.tools.cli import main; sys.exit(main(sys.argv[1:]))"
)


@pytest.mark.zenoh  # the architecture test's rule for tests that run the command (this one opens no session)
def test_without_the_extra_the_command_says_how_to_install_it_in_one_line() -> None:
    result = subprocess.run(
        [sys.executable, "-c", WITHOUT_EXTRA, "ros2", "--uav", "uav0"],
        capture_output=True, text=True, cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == [MISSING_EXTRA]
    assert "pip install 'capataz[ros2]'" in MISSING_EXTRA
    assert result.stdout == ""


@pytest.mark.zenoh  # the architecture test's rule for tests that run the command (this one opens no session)
def test_the_command_is_registered_with_an_example() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "ros2", "--help"], capture_output=True, text=True,
        cwd=ROOT, timeout=60,
    )  # fmt: skip
    assert result.returncode == 0
    assert "--input-uav" in result.stdout and "capataz ros2 --connect" in result.stdout
