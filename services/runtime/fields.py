"""Settings filled by field name: one rule instead of a ``field=source.field`` line per field.

A settings type (a pydantic model or a dataclass) is built from the attributes of its sources that carry
one of its field names: an argparse namespace whose options' ``dest`` is the field's name (``--hfov`` with
``dest="hfov_deg"``), or another settings object that holds a part of its fields (the master's flat
settings hold the yaw stage's grid). Values that are derived rather than copied (parsed ``WIDTHxHEIGHT``,
milliseconds to seconds, a negated ``--no-...`` flag) are given by keyword and win over the sources.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from pydantic import BaseModel

T = TypeVar("T")


def field_names(cls: type[Any]) -> tuple[str, ...]:
    """The constructor fields of a pydantic model or a dataclass."""
    if isinstance(cls, type) and issubclass(cls, BaseModel):
        return tuple(cls.model_fields)
    if dataclasses.is_dataclass(cls):
        return tuple(f.name for f in dataclasses.fields(cls) if f.init)
    raise TypeError(f"{cls!r} is neither a pydantic model nor a dataclass")


def settings_from(cls: type[T], *sources: object, **derived: Any) -> T:
    """``cls`` with each field found by name in the attributes of ``sources`` (a later source wins) or in
    ``derived`` (wins over every source); fields found nowhere keep their defaults."""
    names = field_names(cls)
    values: dict[str, Any] = {}
    for source in sources:
        attributes = vars(source)
        values.update((name, attributes[name]) for name in names if name in attributes)
    return cls(**(values | derived))
