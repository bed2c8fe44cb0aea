"""One-line error texts for the command line: pydantic validation errors and exceptions from zenoh.

A pydantic ``ValidationError`` prints several lines with URLs; zenoh errors carry Rust source paths. The
user of ``capataz`` sees one line that names the option (or environment variable) and its allowed range:
``--fps: must be >= 0, got -5``.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from pydantic import ValidationError

from common.errors import InputError


class UsageError(InputError):
    """An option or environment variable has a value outside its allowed range (``capataz`` exits 2)."""


#: unit suffixes that an option leaves out of its settings field (``--wait-master`` sets ``wait_master_s``)
_UNIT_SUFFIXES = ("_deg_s", "_rad_s", "_m_s", "_s", "_ms", "_m", "_px", "_deg", "_rad", "_hz")
_RUST_LOCATION = re.compile(r"\s*(?:at\s+)?\S+\.rs:\d+(?::\d+)?\.?")
_PYDANTIC_URL = re.compile(r"\s*For further information visit \S+")


def _constraint(error: Mapping[str, Any]) -> str:
    ctx = error.get("ctx") or {}
    kind = str(error.get("type", ""))
    bounds = {
        "greater_than": ("must be >", "gt"),
        "greater_than_equal": ("must be >=", "ge"),
        "less_than": ("must be <", "lt"),
        "less_than_equal": ("must be <=", "le"),
        "multiple_of": ("must be a multiple of", "multiple_of"),
    }
    if kind in bounds:
        text, key = bounds[kind]
        return f"{text} {ctx.get(key)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected', '?')}"
    if kind == "extra_forbidden":
        return "is not a known setting"
    if kind == "missing":
        return "is required"
    return (
        str(error.get("msg", "invalid"))
        .rstrip(".")
        .replace("Input should be", "must be")
        .replace("Value error, ", "")
    )


def option_for(field: str, options: Iterable[str]) -> str:
    """The command-line option that sets settings field ``field`` (``--wait-master`` for ``wait_master_s``),
    or the field's name when no option matches."""
    known = set(options)
    field = field.rsplit(".", 1)[-1]  # a nested settings' field (``camera.hfov_deg``)
    stems = [field[: -len(s)] for s in _UNIT_SUFFIXES if field.endswith(s)]
    # a duration in seconds may be given in milliseconds (``--budget-ms`` sets ``budget_s``)
    candidates = [field, *stems, *(stem + "_ms" for stem in stems if field.endswith("_s"))]
    for name in candidates:
        option = "--" + name.replace("_", "-")
        if option in known:
            return option
    return field


def condense_validation_error(exc: ValidationError, name_of: Callable[[str], str] | None = None) -> str:
    """``--fps: must be >= 0, got -5; --frames: must be >= 2, got 0`` (no URLs, one line)."""
    parts = []
    for error in exc.errors(include_url=False):
        field = ".".join(str(p) for p in error.get("loc", ())) or exc.title
        label = name_of(field) if name_of is not None else field
        got = error.get("input")
        shown = "" if got is None or isinstance(got, Mapping) else f", got {got!r}"
        parts.append(f"{label}: {_constraint(error)}{shown}")
    return "; ".join(parts)


def one_line(text: str) -> str:
    """An exception text on one line: pydantic URLs and Rust source locations removed, lines joined."""
    text = _PYDANTIC_URL.sub("", _RUST_LOCATION.sub("", text))
    return "; ".join(line.strip() for line in text.splitlines() if line.strip())


def number_in(
    kind: Callable[[str], Any], low: float | None = None, high: float | None = None
) -> Callable[[str], Any]:
    """An argparse ``type=`` that accepts ``kind`` values in ``[low, high]`` (one line otherwise:
    ``argument --port: must be an integer in 0..65535, got '99999'``)."""
    name = "an integer" if kind is int else "a number"
    if low is not None and high is not None:
        allowed = f"{name} in {low}..{high}"
    elif low is not None:
        allowed = f"{name} >= {low}"
    else:
        allowed = f"{name} <= {high}" if high is not None else name

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}") from None
        if (low is not None and value < low) or (high is not None and value > high) or value != value:
            raise argparse.ArgumentTypeError(f"must be {allowed}, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse
