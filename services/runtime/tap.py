"""A service that taps key expressions: every sample is handed (raw) to a bounded queue by the Zenoh
callback, and one thread decodes it and calls :meth:`KeyTap.handle` (``capataz record``, ``capataz view``).

A full queue (``queue`` samples, or ``max_queue_bytes`` of payloads when given) drops the sample and counts
it (``dropped_full``): a tap never slows the deployment down. A
malformed sample is counted (``malformed``) and not handled. Log time is the receipt time (ns); publish time
the sample's Zenoh timestamp when it carries one, else None.
"""

from __future__ import annotations

import threading
import time

import zenoh

from common.wire.codec import decode
from common.wire.schema import WireError, WireModel
from services.runtime.handoff import WorkQueue
from services.runtime.service import ServiceRuntime
from services.runtime.transport import TransportSettings, zbytes

_Item = tuple[str, bytes | None, bytes | None, int, int | None]


class KeyTap(ServiceRuntime):
    """Subclasses give :meth:`tap_keys` and :meth:`handle`; :meth:`admit` may refuse samples early."""

    def __init__(
        self,
        node: str,
        index: int,
        transport: TransportSettings,
        queue: int,
        stats_period_s: float = 1.0,
        max_queue_bytes: int | None = None,
    ) -> None:
        super().__init__(node, index, transport, stats_period_s)
        self._queue: WorkQueue[_Item] = WorkQueue(queue)
        self._max_queue_bytes = max_queue_bytes
        self._queued_bytes = 0
        self._bytes_lock = threading.Lock()

    def tap_keys(self) -> tuple[str, ...]:
        raise NotImplementedError

    def admit(self, key: str) -> bool:
        """Called in the Zenoh callback (keep it cheap): False drops the sample before the queue."""
        return True

    def handle(self, key: str, message: WireModel, log_ns: int, publish_ns: int | None) -> None:
        raise NotImplementedError

    def start(self, session: zenoh.Session) -> None:
        for key_expr in self.tap_keys():
            self.subscriptions.append(session.declare_subscriber(key_expr, self._on_sample))
        self.spawn(self._handle_loop, "handle")

    def queue_depths(self) -> dict[str, int]:
        return {"tap": self._queue.depth()}

    def _on_sample(self, sample: zenoh.Sample) -> None:
        log_ns = time.time_ns()
        key = str(sample.key_expr)
        if not self.admit(key):
            return
        stamp = sample.timestamp
        publish_ns = int(stamp.get_time().timestamp() * 1e9) if stamp is not None else None
        payload, attachment = zbytes(sample.payload), zbytes(sample.attachment)
        size = _size(payload) + _size(attachment)
        with self._bytes_lock:
            if self._max_queue_bytes is not None and self._queued_bytes + size > self._max_queue_bytes:
                self.counters.inc("dropped_full")
                return
            self._queued_bytes += size
        if not self._queue.offer((key, payload, attachment, log_ns, publish_ns)):
            self._release(size)
            self.counters.inc("dropped_full")

    def _release(self, size: int) -> None:
        with self._bytes_lock:
            self._queued_bytes -= size

    def _handle_item(self, item: _Item) -> None:
        key, payload, attachment, log_ns, publish_ns = item
        self._release(_size(payload) + _size(attachment))
        try:
            message: WireModel = decode(payload, attachment)
        except WireError as exc:
            self.count_error("malformed", f"bad message on {key}", exc)
            return
        self.handle(key, message, log_ns, publish_ns)

    def _handle_loop(self) -> None:
        while not self.stop_event.is_set():
            item = self._queue.take(0.1)
            if item is not None:
                self._handle_item(item)

    def drain(self) -> None:
        """Handle what is still queued (a recorder's last samples at shutdown)."""
        for item in self._queue.drain():
            self._handle_item(item)


def _size(data: bytes | None) -> int:
    return 0 if data is None else len(data)
