"""A service's counters (:class:`services.runtime.counters.Counters`)."""

from __future__ import annotations

from services.runtime.counters import Counters


def test_counters_and_timings() -> None:
    counters = Counters(window=3)
    assert counters.inc("x") == 1 and counters.inc("x", 4) == 5 and counters.get("y") == 0
    for value in (1.0, 100.0, 2.0, 3.0):
        counters.time_ms("t", value)
    assert counters.counts() == {"x": 5} and counters.median_timings_ms() == {"t": 3.0}
