"""The non-blocking hand-off primitives: latest-wins slot, bounded work queue, counters."""

from __future__ import annotations

import threading

import pytest

from services.runtime.handoff import Counters, HandoffError, LatestSlot, WorkQueue


def test_latest_slot_keeps_the_newest_and_counts_drops() -> None:
    slot: LatestSlot[int] = LatestSlot()
    assert not slot.put(1) and slot.put(2) and slot.put(3)
    assert slot.dropped == 2 and slot.depth() == 1
    assert slot.take(0.0) == 3 and slot.take(0.0) is None
    got: list[int | None] = []
    reader = threading.Thread(target=lambda: got.append(slot.take(5.0)))
    reader.start()
    slot.put(9)
    reader.join()
    assert got == [9]


def test_work_queue_refuses_when_full_and_never_blocks() -> None:
    queue: WorkQueue[str] = WorkQueue(2)
    assert queue.offer("a") and queue.offer("b") and not queue.offer("c")
    assert queue.take(0.0) == "a" and queue.depth() == 1
    assert queue.drain() == ["b"] and queue.take(0.0) is None
    with pytest.raises(HandoffError):
        WorkQueue(0)


def test_counters_and_timings() -> None:
    counters = Counters(window=3)
    assert counters.inc("x") == 1 and counters.inc("x", 4) == 5 and counters.get("y") == 0
    for value in (1.0, 100.0, 2.0, 3.0):
        counters.time_ms("t", value)
    assert counters.counts() == {"x": 5} and counters.median_timings_ms() == {"t": 3.0}
