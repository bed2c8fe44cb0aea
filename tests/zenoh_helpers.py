"""Calm Zenoh tests: a router on a port it chose itself, and bounded waits on conditions instead of sleeps.

- :func:`hub`: an in-process router session listening on ``tcp/127.0.0.1:0``; its real endpoint is read
  from its admin space, so no port is reserved first (binding, closing and re-binding a port races with
  every other process on the host that opens a socket in between).
- :func:`wait_until`: polls a condition with a bound and returns its last value (the test asserts it).
- :func:`matched`: a publisher or querier sees a subscriber / queryable (zenoh's routing status).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from common.dispatch import SELF
from common.wire.codec import encode
from common.wire.schema import WireModel
from services.runtime.transport import TransportSettings, listening_endpoints, open_session

#: bound of every wait: generous, because the suite must pass on a host whose cores are busy
WAIT_S = 30.0


def wait_until(condition: Callable[[], bool], timeout_s: float = WAIT_S, interval_s: float = 0.01) -> bool:
    """Poll ``condition`` until it holds or ``timeout_s`` passed; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return condition()
        time.sleep(interval_s)
    return True


def matched(entity: Any, timeout_s: float = WAIT_S) -> bool:
    """Wait until a publisher (querier) has a matching subscriber (queryable) in its routing tables."""
    return wait_until(lambda: bool(entity.matching_status.matching), timeout_s)


@contextmanager
def hub(lease_ms: int = 1000) -> Iterator[str]:
    """A router session on a free port for the test's services and clients; yields its endpoint."""
    settings = TransportSettings(
        mode="router", listen=("tcp/127.0.0.1:0",), lease_ms=lease_ms, admin_space=True
    )
    with open_session(settings) as router:
        endpoint = next(e for e in listening_endpoints(router) if e.startswith("tcp/127.0.0.1:"))
        yield endpoint


def peer(endpoint: str, lease_ms: int = 1000, **fields: Any) -> TransportSettings:
    """Settings of a peer (a service or the test's client) that joins through the hub at ``endpoint``."""
    return TransportSettings(listen=("tcp/127.0.0.1:0",), connect=(endpoint,), lease_ms=lease_ms, **fields)


def put_message(publisher: Any, message: WireModel) -> None:
    """Publish ``message`` as the services do (payload and its attachment, ``common.wire.codec``)."""
    payload, attachment = encode(message)
    publisher.put(payload, attachment=attachment)


def members_outweigh_master(members: Mapping[str, int]) -> bool:
    """Patches per member of a cluster's yaw estimates: the members (top level, a foreman's entry counting
    its workers' ``foreman>worker`` entries) computed more than the master itself, which takes only the
    share of a member that missed its deadline."""
    return sum(v for k, v in members.items() if k != SELF and ">" not in k) > members.get(SELF, 0)
