"""The dispatch guard's admission (:meth:`DispatchGuard.admit`): a turn's frames checked against the followed
source and the churning members paused, in one call."""

from __future__ import annotations

import time

from services.runtime.counters import Counters
from services.runtime.guard import DispatchGuard


def test_one_admission_refuses_another_source_and_pauses_a_churning_member() -> None:
    counters = Counters()
    guard = DispatchGuard("master", counters)
    for k in range(20):  # a member whose liveliness token flaps
        guard.note_alive("foreman/flaky/0", joined=k % 2 == 0)
    guard.note_alive("foreman/steady/0", joined=True)
    now = time.monotonic()
    assert guard.admit([("camera-a", now), ("camera-b", now), ("camera-a", now)]) == [True, False, True]
    assert counters.get("frames_foreign") == 1
    suspended = guard.monitor().suspended(time.monotonic())
    assert "foreman/flaky/0" in suspended and "foreman/steady/0" not in suspended


def test_a_disabled_guard_admits_every_source_and_pauses_nobody() -> None:
    guard = DispatchGuard("master", Counters(), enabled=False)
    for k in range(20):
        guard.note_alive("foreman/flaky/0", joined=k % 2 == 0)
    now = time.monotonic()
    assert guard.admit([("camera-a", now), ("camera-b", now)]) == [True, True]
    assert not guard.monitor().suspended(time.monotonic())
