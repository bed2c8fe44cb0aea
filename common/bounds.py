"""Declared bounds of the fields of frozen settings dataclasses: the bound stands beside its field, one check.

``hold_s: float = bounded(1.0, gt=0.0)`` declares the default and the bound together (as pydantic's
``Field(default=1.0, gt=0.0)`` does at the wire). A dataclass deriving from :class:`Bounded` checks every
declared bound once constructed (:func:`check_bounds`) and raises :class:`~common.errors.InputError` naming
the class, the field, the bound and the value. A bounded value must be a finite real number (not a bool);
``optional=True`` also lets ``None`` pass (a value "scaled with the scene" or "off"). Rules between fields
stay explicit code in the subclass's ``__post_init__``, after ``super().__post_init__()``.

A field's ``help`` text (:func:`bounded`, or :func:`setting` for a field without bounds) stands beside it
too: a service's settings and its command-line options take the default, the bound and the text from here
(``services.runtime.options``) instead of writing them again.

:func:`check_duration` is the same kind of check for an argument: a filter's time step.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, TypeVar

from common.errors import InputError

T = TypeVar("T")
_KEY = "bounds"
_HELP = "help"


@dataclasses.dataclass(frozen=True)
class Bounds:
    """Open (``gt``, ``lt``) and closed (``ge``, ``le``) limits of one field; None = no limit that side."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    optional: bool = False

    def describe(self) -> str:
        limits = ((">", self.gt), (">=", self.ge), ("<", self.lt), ("<=", self.le))
        parts = [f"{op} {limit:g}" for op, limit in limits if limit is not None]
        return "a finite number" + (" " + " and ".join(parts) if parts else "")

    def holds(self, value: object) -> bool:
        if value is None:
            return self.optional
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            return False
        return (
            (self.gt is None or value > self.gt)
            and (self.ge is None or value >= self.ge)
            and (self.lt is None or value < self.lt)
            and (self.le is None or value <= self.le)
        )


def bounded(
    default: T,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    optional: bool = False,
    help: str = "",
) -> T:
    """A dataclass field with ``default`` whose value :func:`check_bounds` checks against the limits."""
    limits = Bounds(gt=gt, ge=ge, lt=lt, le=le, optional=optional)
    return dataclasses.field(default=default, metadata={_KEY: limits, _HELP: help})


def setting(default: T, *, help: str) -> T:
    """A dataclass field without bounds (a switch, an enum) with ``default`` and its ``help`` text."""
    return dataclasses.field(default=default, metadata={_HELP: help})


def field_help(cls: Any, name: str) -> str:
    """The help text declared with field ``name`` of a dataclass ("" when none)."""
    return str(_field(cls, name).metadata.get(_HELP, ""))


def field_default(cls: Any, name: str) -> Any:
    """The default of field ``name`` of a dataclass (its factory's value for a ``default_factory``)."""
    found = _field(cls, name)
    if found.default is not dataclasses.MISSING:
        return found.default
    if found.default_factory is not dataclasses.MISSING:
        return found.default_factory()
    raise KeyError(f"{getattr(cls, '__name__', cls)}.{name} has no default")


def _field(cls: Any, name: str) -> dataclasses.Field[Any]:
    for found in dataclasses.fields(cls):
        if found.name == name:
            return found
    raise KeyError(f"{getattr(cls, '__name__', cls)} has no field {name!r}")


def field_bounds(cls: Any) -> dict[str, Bounds]:
    """The declared bounds of a dataclass (or instance), by field name."""
    return {f.name: f.metadata[_KEY] for f in dataclasses.fields(cls) if _KEY in f.metadata}


class BoundError(InputError):
    """A settings field outside its declared bound: ``owner.field`` and the ``reason`` (what it must be and
    what it got), apart, so a command line can name its own option for the field."""

    def __init__(self, owner: str, field: str, reason: str) -> None:
        super().__init__(f"{owner}.{field} {reason}")
        self.owner, self.field, self.reason = owner, field, reason


def check_bounds(obj: Any) -> None:
    """Raise :class:`BoundError` naming the first field of ``obj`` outside its declared bounds."""
    for name, limits in field_bounds(obj).items():
        value = getattr(obj, name)
        if not limits.holds(value):
            raise BoundError(type(obj).__name__, name, f"must be {limits.describe()}, got {value!r}")


def check_duration(value: float, name: str = "dt_s") -> float:
    """``value`` as a float when it is a finite number >= 0 (a filter's time step); else InputError."""
    if not (value >= 0.0 and math.isfinite(value)):
        raise InputError(f"{name} must be finite and >= 0, got {value}")
    return float(value)


class Bounded:
    """Base of a frozen settings dataclass whose fields declare bounds: they are checked once constructed.

    A subclass with rules between fields overrides ``__post_init__`` and calls ``super().__post_init__()``
    first.
    """

    def __post_init__(self) -> None:
        check_bounds(self)
