"""The master's frame queue: bounded, oldest dropped first."""

from __future__ import annotations

from typing import TypeVar

from services.runtime.handoff import WorkQueue

T = TypeVar("T")


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
