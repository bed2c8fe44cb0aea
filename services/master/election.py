"""Which of a UAV's masters is active: an election through liveliness tokens.

Every master of a UAV holds a candidate token (``capataz/elect/{uav}/candidate/{node}/{i}``); the active
one also holds the leader token (``.../leader/{node}/{i}``). The rule (:func:`should_lead`):

- a leader keeps the lead (a restarted or new master never pre-empts a working one);
- with no leader alive, the first alive candidate by name takes the lead, so standbys that see the same
  tokens agree on one;
- of two leaders (a healed partition), the one later by name yields.

A killed leader's tokens vanish within milliseconds, a frozen one's within the link lease, and the standby
takes over at its next loop turn. A new master decides nothing for ``settle_s`` after it starts, while the
tokens alive already reach it. Liveliness callbacks only record tokens; :meth:`Election.update` declares
or undeclares the leader token from the master's own thread.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from common.members import Role
from common.wire import keys

logger = logging.getLogger(__name__)


def should_lead(me: str, leading: bool, candidates: set[str], leaders: set[str]) -> bool:
    """Whether master ``me`` should be the active one, given the alive candidate and leader names."""
    others = leaders - {me}
    if leading:
        return not any(other < me for other in others)
    if others:
        return False
    alive = candidates | {me}
    return me == min(alive)


class Election:
    """One master's side of the election for ``uav`` on a zenoh session."""

    def __init__(
        self, session: zenoh.Session, uav: str, node: str, index: int, settle_s: float = 1.0
    ) -> None:
        self.session = session
        self.uav = uav
        self.me = f"{node}/{index}"
        self._leader_key = keys.master_leader_key(uav, node, index)
        self._lock = threading.Lock()
        self._candidates: set[str] = set()
        self._leaders: set[str] = set()
        self._token: Any = None
        self.leading = False
        #: times this master took the lead
        self.takeovers = 0
        self._closed = False
        prefix = keys.election_all(uav).removesuffix("**")
        self._prefix = prefix
        # the tokens alive now arrive as history once the session is connected: no decision before settle_s
        self._settled_at = time.monotonic() + settle_s
        self._subscriber = session.liveliness().declare_subscriber(
            keys.election_all(uav), self._on_token, history=True
        )
        self._candidate = session.liveliness().declare_token(keys.master_candidate_key(uav, node, index))

    def _record(self, key: str, alive: bool) -> None:
        parts = key.removeprefix(self._prefix).split("/")
        if len(parts) != 3 or parts[0] not in ("candidate", "leader"):
            return
        name = f"{parts[1]}/{parts[2]}"
        group = self._candidates if parts[0] == "candidate" else self._leaders
        with self._lock:
            if alive:
                group.add(name)
            else:
                group.discard(name)

    def leaders(self) -> set[str]:
        """The other masters holding the leader token now (``node/index``)."""
        with self._lock:
            return self._leaders - {self.me}

    def _on_token(self, sample: zenoh.Sample) -> None:
        self._record(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    def update(self) -> bool:
        """Apply the rule; returns True exactly when this call made this master the leader."""
        with self._lock:
            if self._closed or time.monotonic() < self._settled_at:
                return False
            lead = should_lead(self.me, self.leading, set(self._candidates), set(self._leaders))
        if lead and not self.leading:
            self._token = self.session.liveliness().declare_token(self._leader_key)
            self.leading = True
            self.takeovers += 1
            logger.info("master %s: active for %s", self.me, self.uav)
            return True
        if not lead and self.leading:
            self._resign()
            logger.warning("master %s: another master leads %s; standing by", self.me, self.uav)
        return False

    def _resign(self) -> None:
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        self.leading = False

    def close(self) -> None:
        with self._lock:
            self._closed = True
        for entity in (self._token, self._candidate, self._subscriber):
            if entity is not None:
                try:
                    entity.undeclare()
                except Exception as exc:  # session closing
                    logger.debug("election undeclare: %s", exc)
        self._token = None
        self.leading = False


class LeaderSessions:
    """The zenoh session id of each alive leader (``node/index``), from the ``replier_id`` of its health
    reply (set by the replying session's zenoh runtime; see :mod:`services.master.published`)."""

    def __init__(self, name: str, count_error: Callable[[str, str, str], None], retry_s: float = 0.5) -> None:
        self.name = name
        self._count_error = count_error
        self.retry_s = retry_s
        self.sessions: dict[str, str] = {}
        self._tried: dict[str, float] = {}
        #: every alive leader's session is known
        self.resolved = False

    def update(self, session: zenoh.Session, leaders: set[str]) -> list[str]:
        """Query the leaders not resolved yet (each at most once per ``retry_s``); the newly resolved
        session ids. A leader that left is forgotten (restarted, it has a new session id)."""
        for name in set(self.sessions) - leaders:
            del self.sessions[name]
        now = time.monotonic()
        found: list[str] = []
        for name in sorted(leaders - set(self.sessions)):
            if now - self._tried.get(name, -math.inf) < self.retry_s:
                continue
            self._tried[name] = now
            node, index = name.rsplit("/", 1)
            key = keys.health_key(Role.MASTER, node, int(index))
            answered = {
                str(reply.replier_id.zid)
                for reply in session.get(key, timeout=self.retry_s)
                if reply.ok is not None and reply.replier_id is not None
            }
            if len(answered) == 1:
                self.sessions[name] = answered.pop()
                found.append(self.sessions[name])
                logger.info("%s: the active master %s is session %s", self.name, name, self.sessions[name])
            elif answered:
                self._count_error(
                    "leader_ambiguous", f"several sessions answer as master {name}", str(answered)
                )
        self.resolved = leaders <= set(self.sessions)
        return found
