"""The non-blocking hand-off primitives: latest-wins slot, bounded work queue, counters."""

from __future__ import annotations

import threading

import pytest

from services.runtime.handoff import FrameQueue, HandoffError, LatestSlot, WorkQueue


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


def test_wake_ends_a_wait_with_nothing_queued() -> None:
    queue: WorkQueue[str] = WorkQueue(1)
    result: list[bool] = []
    waiter = threading.Thread(target=lambda: result.append(queue.wait(60.0)))
    waiter.start()
    for _ in range(600):  # wake until the waiter has returned (a wake before it waits is lost)
        queue.wake()
        waiter.join(0.05)
        if not waiter.is_alive():
            break
    assert result == [False] and queue.depth() == 0


def test_frame_queue_in_order_or_latest_wins() -> None:
    queue: FrameQueue[int] = FrameQueue(3)
    assert not any(queue.put(i) for i in range(3))
    assert queue.put(3) and queue.dropped == 1  # full: the oldest (0) made room
    assert queue.take(0.0) == 1  # in order
    assert queue.take_latest(0.0) == (3, 1)  # 2 skipped for the newest
    assert queue.depth() == 0 and queue.take_latest(0.0) == (None, 0)
