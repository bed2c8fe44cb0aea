"""Transport settings (environment and overrides), zenoh config, and the port a session really listens on."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from services.router.service import RouterService
from services.runtime.transport import (
    TransportError,
    TransportSettings,
    listening_endpoints,
    open_beyond_loopback,
    open_session,
)
from tests.zenoh_helpers import WAIT_S, wait_until


def test_settings_from_environment_and_overrides() -> None:
    env = {
        "CAPATAZ_ZENOH_MODE": "client",
        "CAPATAZ_ZENOH_CONNECT": "tcp/router:7447, tcp/other:7447",
        "CAPATAZ_ZENOH_MULTICAST": "false",
        "CAPATAZ_ZENOH_SHM": "1",
        "CAPATAZ_ZENOH_LEASE_MS": "1500",
    }
    settings = TransportSettings.from_env(env)
    assert settings.mode == "client" and settings.connect == ("tcp/router:7447", "tcp/other:7447")
    assert settings.shared_memory and not settings.multicast_scouting and settings.lease_ms == 1500
    overridden = TransportSettings.from_env(env, mode="peer", shared_memory=False, lease_ms=None)
    assert overridden.mode == "peer" and not overridden.shared_memory and overridden.lease_ms == 1500
    defaults = TransportSettings.from_env({})
    assert defaults.listen == ("tcp/127.0.0.1:0",) and not defaults.multicast_scouting


@pytest.mark.parametrize(
    "env",
    [
        {"CAPATAZ_ZENOH_MODE": "boss"},
        {"CAPATAZ_ZENOH_SHM": "maybe"},
        {"CAPATAZ_ZENOH_LEASE_MS": "soon"},
        {"CAPATAZ_ZENOH_LEASE_MS": "5"},
    ],
)
def test_bad_environment_is_a_transport_error(env: dict[str, str]) -> None:
    with pytest.raises(TransportError):
        TransportSettings.from_env(env)


def test_settings_become_a_zenoh_config() -> None:
    config = TransportSettings(mode="peer", connect=("tcp/127.0.0.1:7447",), lease_ms=2000).to_config()
    assert '"tcp/127.0.0.1:7447"' in config.get_json("connect/endpoints")
    assert config.get_json("scouting/multicast/enabled") == "false"
    assert config.get_json("transport/shared_memory/enabled") == "false"
    with pytest.raises(TransportError):
        TransportSettings(listen=("not an endpoint",)).to_config()


@pytest.mark.zenoh
def test_a_session_on_port_zero_reports_the_port_it_listens_on_and_a_peer_reaches_it() -> None:
    listener = TransportSettings(listen=("tcp/127.0.0.1:0",), admin_space=True)
    with open_session(listener) as session:
        endpoints = listening_endpoints(session)
        assert endpoints and all(not e.endswith(":0") for e in endpoints), endpoints
        tcp = next(e for e in endpoints if e.startswith("tcp/127.0.0.1:"))
        with open_session(TransportSettings(connect=(tcp,))) as other:
            assert wait_until(lambda: session.info.zid() in list(other.info.peers_zid()))
    with (
        open_session(TransportSettings()) as closed_admin,
        pytest.raises(TransportError, match="admin_space"),
    ):
        listening_endpoints(closed_admin, timeout_s=1.0)


@pytest.mark.zenoh
def test_the_router_started_on_port_zero_writes_its_endpoint_file(tmp_path: Path) -> None:
    endpoint_file = tmp_path / "router.endpoint"
    transport = TransportSettings(mode="router", listen=("tcp/127.0.0.1:0",), admin_space=True)
    router = RouterService("r", 0, transport, endpoint_file=endpoint_file)
    runner = threading.Thread(target=router.run, daemon=True)
    runner.start()
    try:
        assert router.started.wait(WAIT_S)
        (endpoint,) = [e for e in endpoint_file.read_text().split() if e.startswith("tcp/127.0.0.1:")]
        assert int(endpoint.rpartition(":")[2]) > 0
        assert not (tmp_path / "router.endpoint.partial").exists()
    finally:
        router.request_stop()
        runner.join(10.0)
    assert not runner.is_alive()


@pytest.mark.parametrize(
    ("listen", "connect", "warned"),
    [
        (("tcp/127.0.0.1:0",), (), False),
        (("tcp/[::1]:0",), ("tcp/localhost:7447",), False),
        (("tcp/0.0.0.0:0",), (), True),
        (("tcp/127.0.0.1:0",), ("tcp/router:7447",), True),
        (("tls/0.0.0.0:0",), ("tls/router:7447",), False),
    ],
)
def test_an_open_session_beyond_loopback_is_named_at_start(
    listen: tuple[str, ...], connect: tuple[str, ...], warned: bool
) -> None:
    """Issue 27: a client of the open profile is warned at start that anyone can read, forge and steer."""
    settings = TransportSettings(listen=listen, connect=connect)
    assert bool(open_beyond_loopback(settings)) is warned
