"""The command line as a newcomer meets it: every documented bad input gives ONE line naming the option (or
variable) and its allowed range, exit 2 for a wrong command line and 1 for a runtime error, never a traceback;
``--version``; a description, an example and the defaults in every sub-command's help; global options after
the sub-command."""

from __future__ import annotations

import argparse
import ast
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from services.tools.cli import (
    COMMAND_MODULES,
    build_parser,
    command_name,
    main,
    requested_module,
    subcommands,
)
from tests.zenoh_helpers import wait_until

ROOT = Path(__file__).resolve().parents[3]


def capataz(
    *args: str, env: dict[str, str] | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    """The real entry point in a child process (its stderr is exactly what a user sees)."""
    return subprocess.run(
        [sys.executable, "-m", "services.tools.cli", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        timeout=timeout,
    )


def assert_one_line(done: subprocess.CompletedProcess[str], code: int, *fragments: str) -> str:
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr and "https://" not in done.stderr, done.stderr
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1, done.stderr
    for fragment in fragments:
        assert fragment in errors[0], errors[0]
    return errors[0]


NO_ROUTER = ["--connect", "tcp/127.0.0.1:9", "--wait-master", "0"]


@pytest.mark.zenoh
@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["camera", "--fps", "-5"], ["--fps", ">= 0", "-5"]),
        (["camera", "--frames", "0"], ["--frames", ">= 2", "0"]),
        (["camera", "--frames", "-1"], ["--frames", ">= 2", "-1"]),
        (["camera", "--in-flight", "-1"], ["--in-flight", ">= 0"]),
        (["camera", "--wait-master", "-1"], ["--wait-master", ">= 0"]),
        (["up", "--cluster", "deploy/clusters/local2x2.yml", "--port", "99999"], ["--port", "0..65535"]),
        (["camera", "--fps", "fast"], ["--fps", "invalid"]),
        (["worker", "--bogus"], ["--bogus"]),
        (["bench", "yaw", "--frames"], ["--frames", "expected one argument"]),
    ],
    ids=lambda v: (
        " ".join(v) if isinstance(v, list) and v and v[0] in {"camera", "up", "worker", "bench"} else None
    ),
)
def test_bad_option_values_give_one_line_and_exit_2(args: list[str], fragments: list[str]) -> None:
    extra = NO_ROUTER if args[0] == "camera" and "--wait-master" not in args else []
    assert_one_line(capataz(*args, *extra), 2, *fragments)


@pytest.mark.zenoh
@pytest.mark.parametrize("case", ["empty", "missing", "file"])
def test_camera_images_that_are_not_a_folder_of_images_give_one_line(case: str, tmp_path: Path) -> None:
    folder = {"empty": tmp_path, "missing": tmp_path / "nowhere", "file": tmp_path / "a.txt"}[case]
    if case == "file":
        folder.write_text("not a folder")
    done = capataz("camera", "--images", str(folder), *NO_ROUTER, timeout=60)
    line = assert_one_line(done, 2, "--images")
    assert str(folder) in line


@pytest.mark.zenoh
def test_a_bad_environment_variable_is_named() -> None:
    done = capataz("router", "--listen", "tcp/127.0.0.1:0", env={"CAPATAZ_ZENOH_MULTICAST": "maybe"})
    assert_one_line(done, 1, "CAPATAZ_ZENOH_MULTICAST", "maybe", "true/false")


@pytest.mark.zenoh
def test_a_pydantic_range_error_is_condensed_to_one_line_without_urls() -> None:
    done = capataz("router", "--listen", "tcp/127.0.0.1:0", "--lease-ms", "5")
    assert_one_line(done, 1, "--lease-ms", "CAPATAZ_ZENOH_LEASE_MS", ">= 100", "got 5")


@pytest.mark.zenoh
def test_up_fails_at_once_when_its_port_is_taken(tmp_path: Path) -> None:
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        done = capataz(
            "up", "--cluster", "deploy/clusters/local2x2.yml", "--port", str(port), "--logs", str(tmp_path),
            "--open",
        )  # fmt: skip
    assert_one_line(done, 1, f"127.0.0.1:{port}", "in use")
    assert "cluster" not in done.stdout  # never "cluster up"


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.startswith("capataz 0.")


def test_every_sub_command_has_a_description_an_example_and_shows_its_defaults() -> None:
    parser = build_parser()
    assert "``" not in (parser.description or "")  # no reST in the top-level help
    for name, sub, _summary, _parent in subcommands(parser):
        assert sub.description, f"capataz {name}: no description"
        assert sub.epilog and f"capataz {name.split()[0]}" in sub.epilog, f"capataz {name}: no example"
        text = sub.format_help()
        for action in sub._actions:
            if not action.option_strings or isinstance(action, argparse._HelpAction):
                continue
            assert action.help, f"capataz {name} {action.option_strings[0]}: no help"
            if not any(action.default is v for v in (None, False, argparse.SUPPRESS)):
                assert "default" in (action.help % vars(action) if "%(" in action.help else action.help) or (
                    "(default: " in text
                ), f"capataz {name} {action.option_strings[0]}: default not shown"


def test_each_command_module_registers_the_command_named_after_it() -> None:
    whole = {name for name, _sub, _summary, parent in subcommands(build_parser()) if " " not in name}
    assert whole == {command_name(m) for m in COMMAND_MODULES}
    for module in COMMAND_MODULES:
        top = {name for name, *_ in subcommands(build_parser((module,))) if " " not in name}
        assert top == {command_name(module)}


@pytest.mark.parametrize(
    ("argv", "module"),
    [
        (["worker", "--node", "h1"], "services.worker"),
        (["-v", "bench", "yaw"], "services.tools.bench"),
        (["-q", "-v", "up"], "services.tools.up"),
        ([], None),
        (["--help"], None),
        (["--version"], None),
        (["-v", "--help", "worker"], None),
        (["wrkr"], None),
        (["--node", "worker"], None),
    ],
)
def test_a_command_line_needs_only_its_own_command_module(argv: list[str], module: str | None) -> None:
    assert requested_module(argv) == module


def loaded_modules(probe: str, prefixes: tuple[str, ...]) -> list[str]:
    """The modules starting with ``prefixes`` that a fresh interpreter has loaded after running ``probe``."""
    script = f"import sys\n{probe}\nprint(sorted(m for m in sys.modules if m.startswith({prefixes!r})))"
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return list(ast.literal_eval(done.stdout.strip()))


def test_a_service_process_imports_no_other_command() -> None:
    """``capataz worker`` parses its command line without importing the bench, localizer or estimator code
    (each cluster process used to pay about 1.5 s of CPU for them at start-up)."""
    probe = (
        "from services.tools.cli import build_parser, requested_module\n"
        "argv = ['worker', '--node', 'h1', '--index', '1']\n"
        "args = build_parser((requested_module(argv),)).parse_args(argv)\n"
        "assert args.handler is not None"
    )
    others = ("services.tools.bench", "services.localizer", "services.estimator", "common.localization")
    assert loaded_modules(probe, (*others, "numba")) == []


def test_the_camera_renders_its_default_flight_without_loading_numba() -> None:
    """``capataz camera`` loaded numba (about 1.2 s of CPU at each start) through the localizer's particle
    filter (for its simulated odometry) and the scene renderer's projection kernel, which it never runs on
    the default flight."""
    probe = (
        "from services.tools.cli import build_parser\n"
        "from services.camera import CameraSettings, simulated_flight\n"
        "args = build_parser(('services.camera',)).parse_args(['camera', '--uav', 'uav0', '--frames', '3'])\n"
        "assert simulated_flight(CameraSettings(frames=3)).frame(2).ndim == 2"
    )
    assert loaded_modules(probe, ("numba", "common.localization.particle_filter")) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["worker", "-v"],
        ["-v", "worker"],
        ["worker", "--quiet"],
        ["bench", "yaw", "--out", "X"],
        ["bench", "--out", "X", "yaw"],
    ],
)
def test_global_options_are_accepted_before_and_after_the_sub_command(argv: list[str]) -> None:
    args = build_parser().parse_args(argv)
    alone = build_parser((str(requested_module(argv)),)).parse_args(argv)  # what `capataz ...` parses with

    def values(namespace: argparse.Namespace) -> dict[str, object]:
        return {k: v for k, v in vars(namespace).items() if k not in ("_parser", "handler")}

    assert values(alone) == values(args)
    if "-v" in argv:
        assert args.verbose is True
    if "--quiet" in argv:
        assert args.quiet is True
    if "--out" in argv:
        assert args.out == Path("X")


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler for SIGTERM (its ``SigCgt`` mask in /proc)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught & (1 << (signal.SIGTERM - 1)))


@pytest.mark.zenoh  # the camera opens a session once it is set up
def test_sigterm_while_a_service_is_still_setting_up_exits_0_regression() -> None:
    """Issue 27: a SIGTERM to a service still setting up (a camera preparing a long flight) killed it (-15)
    instead of ending it cleanly. The command line's own handler, installed before the service's, exits 0."""
    process = subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "camera", "--frames", "100000", "--wait-master", "0",
         "--listen", "tcp/127.0.0.1:0", "--no-multicast"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert wait_until(lambda: _catches_sigterm(process.pid), timeout_s=60.0, interval_s=0.005)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert "Traceback" not in err
