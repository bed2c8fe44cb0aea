"""Services say whether they are connected, and a second service with the same name is refused."""

from __future__ import annotations

import logging
import threading

import pytest

from common.members import Role
from services.runtime import presence
from services.runtime.presence import ConnectionMonitor, DuplicateMemberError
from services.runtime.service import ServiceRuntime
from services.runtime.transport import TransportSettings, open_session
from tests.zenoh_helpers import hub, peer, wait_until


class Camera(ServiceRuntime):
    role = Role.CAMERA


def run_in_thread(service: ServiceRuntime) -> tuple[threading.Thread, dict[str, BaseException]]:
    errors: dict[str, BaseException] = {}

    def target() -> None:
        try:
            service.run()
        except BaseException as exc:  # the test inspects it
            errors["exc"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    return thread, errors


@pytest.mark.zenoh
def test_a_second_service_with_the_same_name_is_refused() -> None:
    with hub() as endpoint:
        first = Camera("cam", 0, peer(endpoint))
        thread_a, errors_a = run_in_thread(first)
        assert first.started.wait(20.0)
        second = Camera("cam", 0, peer(endpoint))
        thread_b, errors_b = run_in_thread(second)
        thread_b.join(20.0)
        assert not thread_b.is_alive()
        assert isinstance(errors_b.get("exc"), DuplicateMemberError), errors_b
        assert "camera/cam/0 is already running" in str(errors_b["exc"])
        other = Camera("cam", 1, peer(endpoint))  # another index is another member
        thread_c, errors_c = run_in_thread(other)
        assert other.started.wait(20.0), errors_c
        for service, thread in ((first, thread_a), (other, thread_c)):
            service.request_stop()
            thread.join(10.0)
        assert not errors_a and not errors_c


@pytest.mark.zenoh
def test_a_peer_without_router_warns_until_it_connects(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(presence, "CONNECT_WARN_PERIOD_S", 0.0)
    lonely = TransportSettings(listen=("tcp/127.0.0.1:0",), connect=("tcp/127.0.0.1:9",))
    with open_session(lonely) as session, caplog.at_level(logging.INFO):
        monitor = ConnectionMonitor("camera/cam/0", lonely.connect, is_router=False)
        assert monitor.check(session) is False
        assert monitor.warned
        assert "no router or peer connected" in caplog.text and "tcp/127.0.0.1:9" in caplog.text
    with hub() as endpoint, open_session(peer(endpoint)) as session, caplog.at_level(logging.INFO):
        assert wait_until(lambda: monitor.check(session))
        assert "camera/cam/0: connected" in caplog.text and not monitor.warned
