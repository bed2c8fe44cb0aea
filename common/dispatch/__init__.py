"""Splitting work among members with time-weighted balancing (pure; the zenoh I/O lives in services)."""

from common.dispatch.dispatcher import (
    SELF,
    Balance,
    Dispatcher,
    DispatchError,
    DispatchSettings,
    Plan,
    SpeedSource,
    largest_remainder,
)

__all__ = [
    "SELF",
    "Balance",
    "DispatchError",
    "DispatchSettings",
    "Dispatcher",
    "Plan",
    "SpeedSource",
    "largest_remainder",
]
