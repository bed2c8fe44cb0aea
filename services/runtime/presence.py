"""Whether a service is connected, and whether its name is already taken (used by ``ServiceRuntime``).

- :class:`ConnectionMonitor`: a warning every few seconds while no router or peer is connected, and a line
  when the connection comes (a peer whose router is down otherwise waits silently forever).
- :class:`TokenWatch`: another live member with the same ``role/node/i`` is seen through liveliness before
  the new one declares its token, and the new one is refused (two cameras named alike would interleave).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence

import zenoh

from common.errors import CapatazError

logger = logging.getLogger(__name__)

#: seconds between warnings while a service has no router or peer connected
CONNECT_WARN_PERIOD_S = 5.0
#: how long a new service watches for another live member of its own name before it declares its token
#: (through a router, a token reached a newly connected peer about 0.35 s after its session opened)
DUPLICATE_SETTLE_S = 0.75


class DuplicateMemberError(CapatazError):
    """Another live service already has this ``role/node/i``."""


class ConnectionMonitor:
    """Call :meth:`check` periodically; it warns while the session has no router and no peer."""

    def __init__(self, name: str, connect: Sequence[str], is_router: bool) -> None:
        self.name = name
        self.connect = tuple(connect)
        self.is_router = is_router
        self._t0 = self._checked_s = time.monotonic()
        self.warned = False

    def check(self, session: zenoh.Session) -> bool:
        now = time.monotonic()
        if list(session.info.routers_zid()) or list(session.info.peers_zid()):
            if self.warned:
                logger.info("%s: connected", self.name)
            self.warned = False
            self._checked_s = now
            return True
        if not self.is_router and now - self._checked_s >= CONNECT_WARN_PERIOD_S:
            logger.warning(
                "%s: no router or peer connected for %.0f s (connect %s): is the router up?",
                self.name,
                now - self._t0,
                ", ".join(self.connect) or "none",
            )
            self.warned = True
            self._checked_s = now
        return False


class TokenWatch:
    """Whether a liveliness token of ``key`` (another process's: ours is declared later) is alive."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.opened_s = time.monotonic()
        self._present = False
        self._cond = threading.Condition()
        self._sub = session.liveliness().declare_subscriber(key, self._on_sample, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        with self._cond:
            self._present = sample.kind == zenoh.SampleKind.PUT
            self._cond.notify_all()

    def wait_gone(self, timeout_s: float) -> bool:
        """True when no token is alive, or it went away within ``timeout_s``."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._present, timeout_s)

    def refuse_duplicate(self, name: str, lease_ms: int, stop: threading.Event) -> None:
        """DuplicateMemberError when the token is alive :data:`DUPLICATE_SETTLE_S` after the session opened.

        A token may outlive a killed process by one lease: a restart waits up to two leases for it to go.
        The watch is closed either way.
        """
        try:
            stop.wait(max(0.0, self.opened_s + DUPLICATE_SETTLE_S - time.monotonic()))
            if not self.wait_gone(2 * lease_ms / 1e3):
                raise DuplicateMemberError(
                    f"{name} is already running elsewhere (duplicate node name): "
                    "choose another --node or --index"
                )
        finally:
            self._sub.undeclare()
