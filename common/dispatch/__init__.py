"""Splitting work among members with time-weighted balancing (pure; the zenoh I/O lives in services)."""

from common.dispatch.dispatcher import SELF, Dispatcher, DispatchError
from common.dispatch.plan import Plan, largest_remainder
from common.dispatch.settings import Balance, DispatchSettings, SpeedSource
from common.dispatch.trust import MemberOutcome, Suspension, TrustMonitor, TrustSettings, outcomes_of_fit

__all__ = [
    "SELF",
    "Balance",
    "DispatchError",
    "DispatchSettings",
    "Dispatcher",
    "MemberOutcome",
    "Plan",
    "SpeedSource",
    "Suspension",
    "TrustMonitor",
    "TrustSettings",
    "largest_remainder",
    "outcomes_of_fit",
]
