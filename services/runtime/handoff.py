"""Hand-off primitives, so that zenoh callbacks never block: :class:`LatestSlot` (latest wins, drops
counted), :class:`WorkQueue` (bounded FIFO, refusals counted), :class:`FrameQueue` (bounded FIFO dropping its
oldest; taken in order or latest-wins). A service's counters are
:class:`services.runtime.counters.Counters`."""

from __future__ import annotations

import threading
from collections import deque
from typing import Generic, TypeVar

from common.errors import CapatazError

T = TypeVar("T")


class HandoffError(CapatazError):
    """A hand-off primitive was built with an impossible size."""


class LatestSlot(Generic[T]):
    """Holds the newest item only: ``put`` never blocks, a replaced item is counted as dropped."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: T | None = None
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Store ``item``; returns True if it replaced an unread one."""
        with self._cond:
            replaced = self._item is not None
            if replaced:
                self.dropped += 1
            self._item = item
            self._cond.notify()
            return replaced

    def take(self, timeout_s: float) -> T | None:
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout_s)
            item, self._item = self._item, None
            return item

    def depth(self) -> int:
        return 0 if self._item is None else 1


class WorkQueue(Generic[T]):
    """Bounded FIFO: ``offer`` never blocks and returns False when full (the caller counts/refuses)."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise HandoffError("queue capacity must be >= 1")
        self._items: deque[T] = deque()
        self._capacity = capacity
        self._cond = threading.Condition()

    def offer(self, item: T) -> bool:
        with self._cond:
            if len(self._items) >= self._capacity:
                return False
            self._items.append(item)
            self._cond.notify()
            return True

    def take(self, timeout_s: float) -> T | None:
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            return self._items.popleft() if self._items else None

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for an item (not taking it); True when one is queued."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            return bool(self._items)

    def wake(self) -> None:
        """Wake a thread waiting in :meth:`take` or :meth:`wait` without queueing anything (for a consumer
        that also waits on something else, e.g. the estimator's frames beside its samples)."""
        with self._cond:
            self._cond.notify()

    def drain(self) -> list[T]:
        with self._cond:
            items = list(self._items)
            self._items.clear()
            return items

    def depth(self) -> int:
        return len(self._items)


class FrameQueue(WorkQueue[T]):
    """A bounded FIFO that drops its oldest item when full (``dropped`` counts each drop once); the rest
    (``take``, ``depth``, ``drain``) is the :class:`WorkQueue`'s."""

    def __init__(self, capacity: int) -> None:
        super().__init__(capacity)
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Append ``item``; True when the oldest item was dropped to make room."""
        with self._cond:
            full = len(self._items) >= self._capacity
            if full:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()
            return full

    def take_latest(self, timeout_s: float) -> tuple[T | None, int]:
        """The newest item and how many older ones were discarded to reach it (latest wins; the caller
        counts them); ``(None, 0)`` after ``timeout_s`` with nothing queued."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout_s)
            if not self._items:
                return None, 0
            item, skipped = self._items[-1], len(self._items) - 1
            self._items.clear()
            return item, skipped
