"""The ``capataz`` command: one sub-command per service, plus ``run``, ``up`` and ``bench``.

Each command module exposes ``register(subparsers)``, which adds its parser and sets
``handler=callable(args) -> int``. Errors of the package become one log line and a non-zero exit.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from common.errors import CapatazError

logger = logging.getLogger("capataz")

#: Modules that register a sub-command, in help order. Add one line per command.
COMMAND_MODULES: tuple[str, ...] = (
    "services.run",
    "services.bench",
    "services.router",
    "services.camera",
    "services.master",
    "services.foreman",
    "services.worker",
    "services.up",
    "services.localizer",
    "services.estimator",
    "services.secure",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="capataz", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname).1s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    try:
        return int(args.handler(args) or 0)
    except CapatazError as exc:
        logger.error("%s: %s", type(exc).__name__, exc)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
