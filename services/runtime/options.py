"""One home for each default: a service's settings field and its command-line option read the core's.

A tunable is declared once, in the core's frozen settings dataclass, with its default, its bound and its help
text (``common.bounds.bounded`` / ``setting``). A service's pydantic settings field takes all three from
there with :func:`from_core` (in the unit the service shows: degrees for a core's radians), and the
command line is generated from the service's settings with :func:`add_options`: the option's default, type,
choices and help are the field's. A service-only field (no core counterpart) is declared once in the
service's settings, with ``Field(default, description=...)``, and generated the same way.

``tests/services/test_one_home.py`` checks, for every command, that each option's default is its field's
and each field's the core's.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import math
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field
from pydantic.fields import FieldInfo

from common.bounds import field_bounds, field_default, field_help

#: suffixes of a field's unit that its option leaves out (``vo_jump_m_s`` is ``--vo-jump``), longest first
UNIT_SUFFIXES = ("_deg_s", "_rad_s", "_m_s", "_s", "_ms", "_m", "_px", "_deg", "_rad", "_hz")


@dataclasses.dataclass(frozen=True)
class Unit:
    """How a service shows a core's value: ``shown(core_value)`` and back (``core(shown_value)``)."""

    name: str
    shown: Callable[[float], float]
    core: Callable[[float], float]


#: a core's radians shown in degrees (rounded to 1e-9 deg, so that 8 deg reads 8, not 7.999999999999999)
DEGREES = Unit("deg", lambda rad: round(math.degrees(rad), 9), math.radians)
_UNITS = {DEGREES.name: DEGREES}


def unit_named(name: str) -> Unit:
    return _UNITS[name]


def from_core(cls: type[Any], name: str, *, unit: Unit | None = None, help: str | None = None) -> Any:
    """A pydantic field with the default, bounds and help text of field ``name`` of the core dataclass
    ``cls`` (converted by ``unit``); the field remembers its origin (``json_schema_extra``)."""
    default = field_default(cls, name)
    limits = field_bounds(cls).get(name)
    convert = unit.shown if unit is not None else (lambda v: v)
    bounds: dict[str, float] = {}
    if limits is not None:
        for key in ("gt", "ge", "lt", "le"):
            value = getattr(limits, key)
            if value is not None:
                bounds[key] = convert(value)
    origin: dict[str, Any] = {"core": f"{cls.__module__}.{cls.__qualname__}.{name}"}
    if unit is not None:
        origin["unit"] = unit.name
    keywords: dict[str, Any] = {
        "default": convert(default) if unit is not None and default is not None else default,
        "description": help if help is not None else field_help(cls, name),
        "json_schema_extra": origin,
        **bounds,
    }
    return Field(**keywords)


def core_origin(info: FieldInfo) -> tuple[str, Unit | None] | None:
    """(``module.Class.field``, unit) of a field made by :func:`from_core`, else None."""
    extra = info.json_schema_extra
    if not isinstance(extra, Mapping) or "core" not in extra:
        return None
    unit = extra.get("unit")
    return str(extra["core"]), unit_named(str(unit)) if unit is not None else None


def flag_of(name: str) -> str:
    """The option of a field by the project's convention: its name without its unit (``--vo-jump``)."""
    for suffix in UNIT_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            name = name[: -len(suffix)]
            break
    return "--" + name.replace("_", "-")


def _plain(annotation: Any) -> Any:
    """``X`` of ``X | None``."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def _described(model: type[Any], name: str) -> tuple[Any, Any, str]:
    """(annotation, default, help text) of field ``name`` of a pydantic model or a core dataclass."""
    if isinstance(model, type) and issubclass(model, BaseModel):
        info = model.model_fields[name]
        return info.annotation, info.get_default(call_default_factory=True), info.description or ""
    return typing.get_type_hints(model)[name], field_default(model, name), field_help(model, name)


def add_options(
    parser: Any,
    model: type[Any],
    names: Iterable[str],
    flags: Mapping[str, str | tuple[str, ...]] | None = None,
    extra: Mapping[str, Mapping[str, Any]] | None = None,
) -> None:
    """An option for each field of ``model`` (a pydantic model or a core dataclass) in ``names``: flag(s)
    from ``flags`` (else :func:`flag_of`), ``dest`` the field's name, default, help text, type or choices
    the field's; a bool is a ``--x/--no-x`` switch; ``extra`` adds or overrides argparse keywords
    (``nargs``, ``metavar``)."""
    flags = flags or {}
    extra = extra or {}
    for name in names:
        annotation, default, help_text = _described(model, name)
        given = flags.get(name, flag_of(name))
        options = (given,) if isinstance(given, str) else tuple(given)
        kind = _plain(annotation)
        kwargs: dict[str, Any] = {"dest": name, "help": help_text}
        if kind is bool:
            kwargs.update(action=argparse.BooleanOptionalAction, default=default)
        elif typing.get_origin(kind) is typing.Literal:
            kwargs.update(choices=sorted(typing.get_args(kind)), default=default)
        elif isinstance(kind, type) and issubclass(kind, enum.Enum):
            kwargs.update(choices=[m.value for m in kind], default=None if default is None else default.value)
        else:
            kwargs["default"] = default
            if kind in (int, float, Path):
                kwargs["type"] = kind
        kwargs.update(extra.get(name, {}))
        parser.add_argument(*options, **kwargs)
