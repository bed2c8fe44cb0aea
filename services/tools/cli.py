"""The capataz command: one sub-command per service, plus run, up, bench and the operator's probes
(status, echo, hz, metrics).

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``handler=callable(args) -> int``. This module gives every parser the same behaviour: a description and an
example per sub-command, every default shown, the global options (``-v``, ``-q``) accepted before or after
the sub-command, and every error on one line: exit 2 for a wrong command line (an option out of its range),
1 for an error while running, never a traceback (``-v`` shows it).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import re
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from importlib import metadata
from typing import Any, NoReturn

from pydantic import ValidationError

from common.errors import CapatazError
from services.runtime import progress
from services.runtime.usage import UsageError, condense_validation_error, one_line, option_for

logger = logging.getLogger("capataz")

#: Modules that register a sub-command, in help order. Add one line per command.
COMMAND_MODULES: tuple[str, ...] = (
    "services.tools.run",
    "services.tools.bench",
    "services.tools.results",
    "services.router",
    "services.camera",
    "services.master",
    "services.foreman",
    "services.worker",
    "services.tools.up",
    "services.localizer",
    "services.estimator",
    "services.tools.loadtest",
    "services.tools.record",
    "services.tools.view",
    "services.tools.secure",
    "services.ros2",
    "services.tools.status",
    "services.tools.echo",
    "services.tools.hz",
    "services.tools.metrics",
    "services.tools.netns",
)

#: One example per sub-command (shown at the end of its --help); keys are the words after ``capataz``.
EXAMPLES: dict[str, str] = {
    "run": "capataz run --only demo_localizer      # one part; merges into out/summary.json",
    "results": "capataz results --summary out/summary.json --bench out/bench   # writes docs/results.md",
    "bench": "capataz bench yaw --frames 300 --out out/bench",
    "bench localizer": "capataz bench localizer --frames 120",
    "bench cluster": "capataz bench cluster --frames 40",
    "bench yaw": "capataz bench yaw --frames 300 --quick",
    "bench estimator": "capataz bench estimator --frames 200",
    "bench all": "capataz bench all --out out/bench",
    "bench security": "capataz bench security --overhead-repeats 5",
    "bench record": "capataz bench record --frames 200 --repeats 4",
    "bench compression": "capataz bench compression --frames 200",
    "bench allocator": "capataz bench allocator --repeats 3 --jobs 30 --patches 30",
    "bench fft": "capataz bench fft --sizes 32 128 --repeats 15",
    "bench refine": "capataz bench refine --caps 4096 48 24 --repeats 5",
    "bench flow": "capataz bench flow --shifts 0.05 0.2 1 --presmooth 1",
    "bench transport": "capataz bench transport --seeds 2 --frames 150 --scenarios field,hover",
    "record": "capataz record --connect tcp/127.0.0.1:7447 --out out/run.mcap --duration 60",
    "view": "capataz view --connect tcp/127.0.0.1:7447",
    "secure": "capataz secure certs --out out/secure/certs --uav uav0 --uav uav1",
    "secure certs": "capataz secure certs --out out/secure/certs --uav uav0 --uav uav1",
    "secure config": "capataz secure config --out deploy/zenoh/secure.json5",
    "secure table": "capataz secure table",
    "router": "capataz router --listen tcp/127.0.0.1:7447",
    "camera": "capataz camera --connect tcp/127.0.0.1:7447 --uav uav0 --fps 20 --frames 400",
    "master": "capataz master --connect tcp/127.0.0.1:7447 --uav uav0 --topology master-foreman-worker",
    "foreman": "capataz foreman --connect tcp/127.0.0.1:7447 --node h1",
    "worker": "capataz worker --connect tcp/127.0.0.1:7447 --node h1 --index 0",
    "up": "capataz up --cluster deploy/clusters/local2x2.yml --frames 400",
    "localizer": "capataz localizer --connect tcp/127.0.0.1:7447 --uav uav1 --use-vo",
    "bench ros2": "capataz bench ros2 --seconds 20",
    "bench consistency": "capataz bench consistency --quick",
    "bench dispatch": "capataz bench dispatch --frames 100",
    "netns": "capataz netns check",
    "netns check": "capataz netns check",
    "netns cleanup": "capataz netns cleanup --prefix cz",
    "ros2": "capataz ros2 --connect tcp/127.0.0.1:7447 --uav uav0 --input-uav uav0 --domain-id 42",
    "estimator": "capataz estimator --connect tcp/127.0.0.1:7447 --uav uav0 --external-yaw",
    "status": "capataz status --connect tcp/127.0.0.1:7447 --watch",
    "echo": "capataz echo capataz/uav/uav0/yaw --connect tcp/127.0.0.1:7447 --count 5",
    "hz": "capataz hz capataz/uav/uav0/camera --connect tcp/127.0.0.1:7447 --duration 10",
    "metrics": "capataz metrics --port 9464 --connect tcp/127.0.0.1:7447",
}

GLOBAL_OPTIONS = ("-v", "--verbose", "-q", "--quiet")


def command_name(module: str) -> str:
    """The sub-command a module of :data:`COMMAND_MODULES` registers (``services.tools.bench`` ->
    ``bench``)."""
    return module.rsplit(".", 1)[-1]


def requested_module(argv: Sequence[str]) -> str | None:
    """The one command module a command line needs, or None when it needs them all (help, no command, an
    unknown command). Every service starts through this CLI: importing only its own module saves each
    process about 1.5 s of CPU (the bench modules pull in numba's compiler and the localizer)."""
    for token in argv:
        if token in GLOBAL_OPTIONS:
            continue
        if token.startswith("-"):
            return None
        return next((m for m in COMMAND_MODULES if command_name(m) == token), None)
    return None


def version() -> str:
    try:
        return metadata.version("capataz")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples kept as written; every option's default shown (unless its help says it)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (
            not action.option_strings
            or "default" in text.lower()
            or any(action.default is v for v in (None, False, argparse.SUPPRESS))
            or isinstance(action, (argparse._HelpAction, argparse._VersionAction))
        ):
            return text
        return f"{text} (default: %(default)s)".strip()


#: a negative number in the float notations (``-1``, ``-.5``, ``-2.5e-15``, ``-1E3``; ``-inf`` is not one)
NEGATIVE_NUMBER = re.compile(r"^-(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$")


class CapatazParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``capataz camera: error: argument --fps: ...``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        # a negative number is a value, in every notation (argparse's own pattern misses -2.5e-15 and -1e3,
        # and then reads them as unknown options): ``--initial-pose -2.5e-15 0 0 ...``
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_global_options(parser: argparse.ArgumentParser, top: bool) -> None:
    """``-v``/``-q`` on the top parser (with defaults) and on every sub-command (given or absent)."""
    default: dict[str, Any] = {} if top else {"default": argparse.SUPPRESS}
    group = parser.add_argument_group("global options")
    group.add_argument("-v", "--verbose", action="store_true", help="debug logging, tracebacks", **default)
    group.add_argument(
        "-q", "--quiet", action="store_true", help="warnings only, no progress bars", **default
    )


def subcommands(parser: argparse.ArgumentParser, path: str = "") -> Iterator[tuple[str, Any, str, Any]]:
    """(``"bench yaw"``, sub-parser, its one-line help, its parent) for every sub-command, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                full = f"{path} {name}".strip()
                yield full, sub, helps.get(name, ""), parser
                yield from subcommands(sub, full)


def _option_strings(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


def _finish(parser: argparse.ArgumentParser) -> None:
    for full, sub, summary, parent in subcommands(parser):
        if sub.description is None:
            sub.description = summary[:1].upper() + summary[1:] + ("." if summary else "")
        if sub.epilog is None and full in EXAMPLES:
            sub.epilog = f"example:\n  {EXAMPLES[full]}"
        if "-v" not in _option_strings(sub):
            add_global_options(sub, top=False)
        # options of the parent (``bench --out``) are accepted after the child's name as well
        for action in parent._actions:
            own = _option_strings(sub)
            if action.option_strings and not set(action.option_strings) & own and action.dest != "help":
                if isinstance(action, (argparse._SubParsersAction, argparse._VersionAction)):
                    continue
                sub.add_argument(
                    *action.option_strings,
                    dest=action.dest,
                    type=action.type,
                    default=argparse.SUPPRESS,
                    help=f"{action.help} (also accepted before the name)",
                )
        sub.set_defaults(_parser=sub)


def build_parser(modules: Sequence[str] = COMMAND_MODULES) -> argparse.ArgumentParser:
    """The whole command line, or only ``modules``' sub-commands (what one command needs to parse)."""
    parser = CapatazParser(
        prog="capataz",
        description=(
            "Ground station for UAV visual state estimation: a yaw cluster, an EKF with visual odometry\n"
            "and a particle-filter localizer, as Zenoh microservices.\n"
            "'capataz COMMAND --help' describes a command."
        ),
        epilog=(
            "examples:\n"
            "  capataz run                                         # the embedded default, report in out/\n"
            "  capataz up --cluster deploy/clusters/local2x2.yml  # a local cluster with its camera\n"
            "  capataz bench yaw                                   # a benchmark, out/bench/yaw.json"
        ),
    )
    parser.add_argument("--version", action="version", version=f"capataz {version()}")
    add_global_options(parser, top=True)
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in modules:
        importlib.import_module(name).register(subparsers)
    _finish(parser)
    return parser


def _report(args: argparse.Namespace, exc: BaseException, code: int) -> int:
    prog = getattr(getattr(args, "_parser", None), "prog", "capataz")
    if isinstance(exc, ValidationError):
        options = _option_strings(args._parser) if hasattr(args, "_parser") else set()
        text = condense_validation_error(exc, lambda field: option_for(field, options))
    elif isinstance(exc, CapatazError):
        text = one_line(str(exc))
    elif isinstance(exc, OSError):  # a file or folder that cannot be read or written, a port in use
        where = f"{exc.filename}: " if exc.filename else ""
        text = f"{where}{exc.strerror or one_line(str(exc))}"
    else:
        text = f"{type(exc).__name__}: {one_line(str(exc))} (an internal error; -v shows the traceback)"
    if args.verbose:
        logger.exception("%s", text)
    print(f"{prog}: error: {text}", file=sys.stderr)
    return code


def _exit_on_sigterm(*_args: Any) -> NoReturn:
    raise SystemExit(0)


def main(argv: Sequence[str] | None = None) -> int:
    """``capataz``'s entry point; called with ``argv`` (in-process, e.g. tests), it leaves the caller's
    SIGTERM handling as it found it."""
    in_process = argv is not None
    # a SIGTERM before a command installs its own handling (a service still importing its module on a busy
    # host, a camera rendering its flight, a localizer loading its model) ends it cleanly, exit 0, instead
    # of killing it (-15): installed first, before the command's module is imported
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM)
    if in_main_thread:
        signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        module = requested_module(argv)
        parser = build_parser(COMMAND_MODULES if module is None else (module,))
        args = parser.parse_args(argv)
    except BaseException:
        if in_process and in_main_thread and previous is not None:
            signal.signal(signal.SIGTERM, previous)
        raise
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO,
        format="%(asctime)s %(levelname).1s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    progress.configure(quiet=args.quiet)
    try:
        code = int(args.handler(args) or 0)
    except (ValidationError, UsageError) as exc:
        code = _report(args, exc, 2)
    except (CapatazError, OSError) as exc:
        code = _report(args, exc, 1)
    except KeyboardInterrupt:
        code = 130
    except SystemExit as exc:  # a SIGTERM while setting up (_exit_on_sigterm), or a command's own exit
        code = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
    except Exception as exc:  # never a traceback for the user; -v shows it
        code = _report(args, exc, 1)
    finally:
        # a process keeps its handler to the end (a late SIGTERM while exiting is still a clean exit)
        if in_process and in_main_thread and previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if not in_process and module in SERVICE_MODULES:
        _exit_now(code)
    return code


#: the long-running services: once one has stopped (its session closed, its files written), its process
#: exits at once, without the interpreter's teardown of numba, OpenCV and zenoh's runtime (about 0.5 s of
#: CPU per process: 13 services stopped together on a busy 2-core host took up to 1.5 s)
SERVICE_MODULES = frozenset(m for m in COMMAND_MODULES if not m.startswith("services.tools."))


def _exit_now(code: int) -> NoReturn:
    logging.shutdown()  # flushes every handler
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
