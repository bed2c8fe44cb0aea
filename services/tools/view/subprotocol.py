"""Both names of Foxglove's WebSocket protocol on the viewer's port.

foxglove-sdk serves the protocol under the subprotocol name ``foxglove.sdk.v1`` and answers HTTP 400 to a
client that offers only ``foxglove.websocket.v1``, the name of the same protocol before the SDK (Foxglove's
stance: the two are identical but for the name). Clients built before it (older Foxglove apps, Lichtblick,
roslibjs-foxglove) offer only the old name. :class:`SubprotocolFront` listens on the viewer's port and
forwards each connection to the SDK's server on an internal loopback port; for a client that offers only the
old name it renames the offer in the opening handshake, and the server's answer back, then copies bytes both
ways. A client that offers the new name passes unchanged.
"""

from __future__ import annotations

import logging
import re
import selectors
import socket
import threading

logger = logging.getLogger(__name__)

LEGACY = b"foxglove.websocket.v1"
CURRENT = b"foxglove.sdk.v1"
#: the largest opening handshake read (an HTTP upgrade request is a few hundred bytes)
MAX_HEAD_BYTES = 16384
_PROTOCOL_HEADER = re.compile(rb"^(sec-websocket-protocol)[ \t]*:[ \t]*([^\r\n]*)", re.I | re.M)


def rename_offer(head: bytes) -> tuple[bytes, bool]:
    """The request head with ``foxglove.websocket.v1`` offered as ``foxglove.sdk.v1`` when the client offers
    only the old name, and whether it was renamed."""
    renamed = False

    def offer(match: re.Match[bytes]) -> bytes:
        nonlocal renamed
        offers = [o.strip() for o in match.group(2).split(b",")]
        if LEGACY not in offers or CURRENT in offers:
            return match.group(0)
        renamed = True
        return match.group(1) + b": " + b", ".join(CURRENT if o == LEGACY else o for o in offers)

    return _PROTOCOL_HEADER.sub(offer, head), renamed


def rename_answer(head: bytes) -> bytes:
    """The server's handshake answer with the chosen ``foxglove.sdk.v1`` named ``foxglove.websocket.v1``."""
    return _PROTOCOL_HEADER.sub(
        lambda m: m.group(1) + b": " + (LEGACY if m.group(2).strip() == CURRENT else m.group(2)), head
    )


def read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (up to and including the blank line) and whatever followed it; ``(b"", ...)`` when the
    peer closed first or sent more than :data:`MAX_HEAD_BYTES` without a blank line."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk or len(data) + len(chunk) > MAX_HEAD_BYTES:
            return b"", b""
        data += chunk
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


class SubprotocolFront:
    """Listens on ``(host, port)`` and forwards every connection to ``127.0.0.1:backend_port``."""

    def __init__(self, host: str, port: int, backend_port: int, max_connections: int = 16) -> None:
        self.backend_port = backend_port
        self.max_connections = max_connections
        self._listener = socket.create_server((host, port))  # OSError when the port is taken
        self._listener.settimeout(0.2)
        self._stop = threading.Event()
        self._active: set[socket.socket] = set()
        self._lock = threading.Lock()
        self.renamed = 0
        self._thread = threading.Thread(target=self._accept, name="view-front", daemon=True)

    @property
    def port(self) -> int:
        return int(self._listener.getsockname()[1])

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self._listener.close()
        with self._lock:
            for sock in list(self._active):
                sock.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return  # the listener closed
            with self._lock:
                full = len(self._active) >= 2 * self.max_connections
            if full:
                client.close()
                continue
            threading.Thread(target=self._serve, args=(client,), name="view-conn", daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        backend = None
        try:
            client.settimeout(5.0)
            head, rest = read_head(client)
            if not head:
                return
            head, legacy = rename_offer(head)
            backend = socket.create_connection(("127.0.0.1", self.backend_port), timeout=5.0)
            with self._lock:
                self._active |= {client, backend}
            backend.sendall(head + rest)
            answer, more = read_head(backend)
            if not answer:
                return
            if legacy:
                answer = rename_answer(answer)
                with self._lock:
                    self.renamed += 1
            client.sendall(answer + more)
            client.settimeout(None)
            backend.settimeout(None)
            self._pump(client, backend)
        except OSError as exc:
            logger.debug("viewer connection ended: %s", exc)
        finally:
            with self._lock:
                self._active -= {client, backend} if backend is not None else {client}
            client.close()
            if backend is not None:
                backend.close()

    def _pump(self, a: socket.socket, b: socket.socket) -> None:
        """Copy bytes both ways until either side closes or the front stops."""
        with selectors.DefaultSelector() as selector:
            selector.register(a, selectors.EVENT_READ, b)
            selector.register(b, selectors.EVENT_READ, a)
            while not self._stop.is_set():
                for key, _ in selector.select(timeout=0.2):
                    source: socket.socket = key.fileobj  # type: ignore[assignment]
                    data = source.recv(65536)
                    if not data:
                        return
                    key.data.sendall(data)
