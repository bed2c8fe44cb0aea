"""One error path for every command (issue 28 section 3): a wrong command line is one line naming the option
and what it accepts, exit 2; a failure while running (a file that cannot be read or written, a port in use) is
one line naming the file or option, exit 1; never a traceback, a pydantic dump or "an internal error".

Each row is a command line a user typed (the issue's list, plus each command's number options) run through
``capataz``'s own ``main`` in this process; the rows that need a Zenoh session run as processes."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from services.tools.cli import main

WRONG_COMMAND_LINES: list[tuple[list[str], str]] = [
    (["localizer", "--initial-pose", "1", "2", "3"], "--initial-pose: a pose is 6 numbers"),
    (["localizer", "--particles", "0"], "--particles: must be >= 2, got 0"),
    (["master", "--grid", "0x5"], "--grid (columns): must be a finite number >= 1"),
    (["master", "--grid", "8by5"], "--grid must look like 8x5"),
    (["master", "--patch-size", "3"], "--patch-size: must be a finite number >= 8"),
    (["master", "--budget-ms", "1e6"], "--budget-ms: must be in (0, 10000] ms"),
    (["camera", "--resolution", "10x"], "--resolution must look like 752x480, got '10x'"),
    (["camera", "--images", "no/such/folder"], "--images no/such/folder: no such folder"),
    (["worker", "--index", "-1"], "argument --index: must be an integer >= 0, got '-1'"),
    (["worker", "--lease-ms", "0"], "argument --lease-ms: must be an integer >= 1"),
    (["worker", "--stats-period", "nan"], "argument --stats-period: must be a number in 0.01..3600.0"),
    (["router", "--connect", "garbage"], "argument --connect: must be PROTOCOL/ADDRESS"),
    (["router", "--listen", "tcp/"], "argument --listen: must be PROTOCOL/ADDRESS"),
    (["loadtest", "--streams", "0"], "argument --streams: must be an integer in 1..256, got '0'"),
    (["loadtest", "--duration", "-1"], "argument --duration: must be a number in 0.1..3600.0"),
    (["loadtest", "--fps", "1000"], "argument --fps: must be a number in 0.1..200.0"),
    (["camera", "--fps", "-5"], "--fps"),
]


@pytest.mark.parametrize(
    ("argv", "expected"), WRONG_COMMAND_LINES, ids=[" ".join(a) for a, _ in WRONG_COMMAND_LINES]
)
def test_a_wrong_command_line_is_one_line_naming_the_option_and_exit_2(
    argv: list[str], expected: str, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1 and expected in lines[0], lines
    assert "Traceback" not in err and "internal error" not in err and "validation error" not in err


def test_a_negative_number_in_exponent_notation_is_a_value_not_an_option(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``--initial-pose -2.5e-15 0 0 0 0 1`` was refused by argparse as an unknown option."""
    code = main(
        ["localizer", "--initial-pose", "-2.5e-15", "0", "0", "0", "0", "1", "--model", "no/such.cao"]
    )
    err = capsys.readouterr().err
    assert code == 1 and "expected at least one argument" not in err and "no/such.cao" in err, err


def test_a_file_that_cannot_be_written_is_one_line_naming_it_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "missing" / "dir" / "camera.yaml"
    code = main(["camera", "--write-calibration", str(target)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1 and str(target) in lines[0], lines
    assert "internal error" not in err and "Traceback" not in err


def test_an_output_folder_that_cannot_be_made_is_one_line_before_any_demo_runs(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code = main(["run", "--out", "/proc/capataz-out", "--only", "demo_localizer"])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 1 and len(lines) == 1 and "/proc/capataz-out" in lines[0], lines
    assert "demo" not in err and "internal error" not in err


def test_a_calibration_whose_matrix_does_not_fill_its_size_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "short.yaml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 752\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
        "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 400., 0., 0., 400., 1., 2. ]\n"
    )
    code = main(["master", "--calibration", str(path)])
    err = capsys.readouterr().err
    assert code in (1, 2) and f"{path}: camera_matrix says 3x3 but has 6 values" in err, err
    assert "OpenCV" not in err and "internal error" not in err


def _capataz(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "services.tools.cli", *args], capture_output=True, text=True, timeout=120
    )


@pytest.mark.zenoh  # opens a session before it serves
def test_the_viewer_on_a_taken_port_is_one_line_naming_the_port() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = _capataz("view", "--port", str(port), "--no-multicast")
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert done.returncode == 1 and len(errors) == 1 and f"--port {port}" in errors[0], done.stderr
    assert "internal error" not in done.stderr and "Traceback" not in done.stderr


@pytest.mark.zenoh  # would open a session
def test_a_tls_connect_endpoint_without_a_ca_is_refused_instead_of_retrying_in_silence() -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAPATAZ_ZENOH_TLS")}
    done = subprocess.run(
        [sys.executable, "-m", "services.tools.cli", "worker", "--connect", "tls/127.0.0.1:9",
         "--no-multicast"], capture_output=True, text=True, timeout=120, env=env,
    )  # fmt: skip
    assert done.returncode == 1 and "needs the CA certificate" in done.stderr, done.stderr
