"""``ServiceRuntime``'s shutdown rules: the default ``stop()`` undeclares the subscriptions only, and
``publish`` turns a put that fails because the service is stopping into ``False`` (not a thread crash)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
import zenoh

from common.members import Role
from common.wire.codec import decode, encode
from common.wire.messages import PoseEstimate, Stats
from services.runtime.service import ServiceRuntime
from services.runtime.transport import TransportSettings


def _pose() -> PoseEstimate:
    return PoseEstimate(
        uav="uav0", stamp_s=1.0, p_world_body_m=np.zeros(3), q_world_body=np.array([1.0, 0, 0, 0]),
        covariance=np.eye(6), source="vo",
    )  # fmt: skip


class Publisher:
    """A stand-in publisher: records puts, or raises zenoh's error once closed."""

    def __init__(self) -> None:
        self.closed = False
        self.sent: list[tuple[bytes, bytes, dict[str, Any]]] = []

    def put(self, payload: bytes, attachment: bytes, **options: Any) -> None:
        if self.closed:
            raise zenoh.ZError("Undeclared publisher")
        self.sent.append((bytes(payload), bytes(attachment), options))


class Entity:
    def __init__(self) -> None:
        self.undeclared = 0

    def undeclare(self) -> None:
        self.undeclared += 1


class _Probe(ServiceRuntime):
    role = Role.CAMERA


def _service() -> ServiceRuntime:
    return _Probe("test", 0, TransportSettings())


def test_a_service_without_a_role_is_refused_instead_of_announcing_itself_as_a_worker() -> None:
    """Regression: the base's default role was WORKER, so a service that forgot its own was a worker to the
    cluster's membership (a dispatcher would send it patches)."""
    with pytest.raises(TypeError, match="must set its role"):
        ServiceRuntime("test", 0, TransportSettings())


def test_publish_encodes_and_puts_with_the_given_options() -> None:
    service, publisher = _service(), Publisher()
    assert service.publish(publisher, _pose(), congestion_control="x")
    payload, attachment, options = publisher.sent[0]
    assert decode(payload, attachment, PoseEstimate).stamp_s == 1.0
    assert options == {"congestion_control": "x"}


def test_a_put_that_fails_while_stopping_returns_false_and_one_that_fails_while_running_raises() -> None:
    service, publisher = _service(), Publisher()
    publisher.closed = True
    with pytest.raises(zenoh.ZError):
        service.publish(publisher, _pose())
    service.request_stop()
    assert service.publish(publisher, _pose()) is False


def test_the_default_stop_undeclares_the_subscriptions_only() -> None:
    service = _service()
    subscriptions = [Entity(), Entity()]
    service.subscriptions.extend(subscriptions)
    service.stop()
    assert [s.undeclared for s in subscriptions] == [1, 1]


def test_stats_carry_the_process_cpu_time_and_it_grows_with_work() -> None:
    service = _service()
    first = service.stats_message().cpu_s
    c0 = time.process_time()
    while time.process_time() - c0 < 0.05:  # burn 50 ms of CPU (a bound on work, not on wall time)
        np.linalg.svd(np.ones((64, 64)))
    second = service.stats_message()
    assert first > 0.0 and second.cpu_s >= first + 0.04
    assert decode(*encode(second), Stats).cpu_s == second.cpu_s  # it crosses the wire
