"""The package's one exception root.

Every module that can fail defines its own subclass of :class:`CapatazError`.
Validation failures at a boundary raise :class:`InputError`, which is also a
``ValueError`` so that ``check_*`` validators behave like the standard library's.
"""

from __future__ import annotations


class CapatazError(Exception):
    """Root of every error raised by capataz."""


class InputError(CapatazError, ValueError):
    """An array or message failed validation at a boundary (wrong shape, dtype, NaN, ...)."""
