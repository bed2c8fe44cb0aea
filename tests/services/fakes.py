"""Stand-ins for zenoh objects in tests that need no network: payload bytes and a reply/query channel."""

from __future__ import annotations

from typing import Any

import zenoh


class FakeBytes:
    """``zenoh.ZBytes`` as the code reads it."""

    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class FakeChannel:
    """A zenoh FIFO channel holding ``items``; once empty it behaves as closed (``recv`` raises ZError)."""

    def __init__(self, items: list[Any]) -> None:
        self._items = list(items)

    def recv(self) -> Any:
        if not self._items:
            raise zenoh.ZError("channel is empty and closed")
        return self._items.pop(0)

    def try_recv(self) -> Any:
        return self._items.pop(0) if self._items else None


class FakePublisher:
    """A publisher that records what is put on it."""

    def __init__(self) -> None:
        self.puts: list[tuple[bytes, bytes]] = []

    def put(self, payload: bytes, attachment: bytes) -> None:
        self.puts.append((payload, attachment))
