"""A Zenoh configuration file under each service's settings; credentials from files or environment only;
the router honours access control and TLS given that way (issue 12's two router bugs)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from services.runtime import zconfig
from services.runtime.transport import TransportError, TransportSettings, open_session

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    """A port free right now (the router binds it a moment later; good enough on loopback in a test)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def write(path: Path, config: dict[str, object]) -> Path:
    path.write_text("// test config\n" + json.dumps(config))
    return path


def test_the_file_wins_over_defaults_and_explicit_settings_win_over_the_file(tmp_path: Path) -> None:
    path = write(
        tmp_path / "z.json5",
        {"listen": {"endpoints": ["tcp/127.0.0.1:7"]}, "transport": {"link": {"tx": {"lease": 7000}}}},
    )
    config = TransportSettings.from_env(environ={"CAPATAZ_ZENOH_CONFIG": str(path)}).to_config()
    assert zconfig.get(config, "listen/endpoints") == ["tcp/127.0.0.1:7"]
    assert zconfig.get(config, "transport/link/tx/lease") == 7000
    assert zconfig.get(config, "scouting/multicast/enabled") is False  # not in the file: our default
    explicit = TransportSettings.from_env(
        environ={"ZENOH_CONFIG": str(path), "CAPATAZ_ZENOH_LEASE_MS": "3000"}, listen=("tcp/127.0.0.1:9",)
    ).to_config()
    assert zconfig.get(explicit, "listen/endpoints") == ["tcp/127.0.0.1:9"]
    assert zconfig.get(explicit, "transport/link/tx/lease") == 3000


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"CAPATAZ_ZENOH_CONFIG": "/nonexistent/z.json5"}, "no such file"),
        ({"CAPATAZ_ZENOH_TLS_CERT": "/etc/hostname"}, "needs its private key"),
        ({"CAPATAZ_ZENOH_TLS_CA": "/etc/hostname"}, "not a PEM file"),
        ({"CAPATAZ_ZENOH_USRPWD_FILE": "/etc/hostname"}, "user:password"),
        ({"CAPATAZ_ZENOH_LISTEN": "tls/127.0.0.1:0"}, "CAPATAZ_ZENOH_TLS_KEY"),
    ],
)
def test_bad_configuration_or_credentials_are_one_clear_error(env: dict[str, str], message: str) -> None:
    with pytest.raises(TransportError, match=message) as info:
        TransportSettings.from_env(environ=env).to_config()
    assert "\n" not in str(info.value)


def test_a_config_file_that_is_not_json5_is_one_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(TransportError, match=r"bad\.json5"):
        TransportSettings.from_env(environ={"CAPATAZ_ZENOH_CONFIG": str(bad)}).to_config()


def test_credentials_come_from_environment_files(tmp_path: Path, certs: Path) -> None:
    secret = tmp_path / "usrpwd"
    secret.write_text("camera:s3cret\n")
    config = TransportSettings.from_env(
        environ={
            "CAPATAZ_ZENOH_TLS_CA": str(certs / "ca.pem"),
            "CAPATAZ_ZENOH_TLS_CERT": str(certs / "worker.h1.pem"),
            "CAPATAZ_ZENOH_TLS_KEY": str(certs / "worker.h1.key"),
            "CAPATAZ_ZENOH_USRPWD_FILE": str(secret),
        }
    ).to_config()
    tls = zconfig.get(config, "transport/link/tls")
    assert tls["enable_mtls"] is True and tls["listen_private_key"].endswith("worker.h1.key")
    assert zconfig.get(config, "transport/auth/usrpwd/user") == "camera"


def test_services_take_no_credentials_on_the_command_line() -> None:
    from services.tools.cli import build_parser

    for command in ("worker", "router", "master", "foreman", "camera"):
        options = build_parser().parse_args([command]).__dict__
        assert not any(word in k for k in options for word in ("key", "password", "cert", "ca_"))


def router(env: dict[str, str], *args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "services.tools.cli", "router", "--no-multicast", *args],
        env={**os.environ, **env},
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )


def wait_listening(process: subprocess.Popen[bytes], port: int) -> None:
    import socket

    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        assert process.poll() is None, process.stdout.read().decode() if process.stdout else ""
        with socket.socket() as sock:
            if sock.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise AssertionError("router did not listen")


def stop(process: subprocess.Popen[bytes]) -> str:
    process.terminate()
    out, _ = process.communicate(timeout=10)
    return out.decode()


@pytest.mark.zenoh
def test_router_honours_access_control_given_through_zenoh_config_regression(tmp_path: Path) -> None:
    """Issue 12: ``capataz router`` ignored the policy of ZENOH_CONFIG; now a denied put is not routed."""
    port = free_port()
    acl = {
        "enabled": True,
        "default_permission": "allow",
        "rules": [{"id": "no", "permission": "deny", "messages": ["put"], "key_exprs": ["t/denied"]}],
        "subjects": [{"id": "all"}],
        "policies": [{"rules": ["no"], "subjects": ["all"]}],
    }
    path = write(tmp_path / "acl.json5", {"access_control": acl})
    process = router({"ZENOH_CONFIG": str(path)}, "--listen", f"tcp/127.0.0.1:{port}")
    try:
        wait_listening(process, port)
        got: list[str] = []
        lock = threading.Lock()

        def on(sample: zenoh.Sample) -> None:
            with lock:
                got.append(str(sample.key_expr))

        client = TransportSettings(mode="client", connect=(f"tcp/127.0.0.1:{port}",), listen=())
        with open_session(client) as sub_session, open_session(client) as pub_session:
            sub = sub_session.declare_subscriber("t/*", on)
            # the subscription is routed once a probe arrives (polled with a bound, no fixed sleep)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and "t/probe" not in got:
                pub_session.put("t/probe", b"x")
                time.sleep(0.05)
            assert "t/probe" in got, "the subscription was never routed"
            for _ in range(5):
                pub_session.put("t/denied", b"x")
                pub_session.put("t/allowed", b"x")
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and got.count("t/allowed") < 5:
                time.sleep(0.05)
            sub.undeclare()
    finally:
        log = stop(process)
    assert got.count("t/allowed") == 5 and "t/denied" not in got, got
    assert "access control on" in log


@pytest.mark.zenoh
def test_router_listens_on_tls_with_credentials_from_the_environment_regression(certs: Path) -> None:
    """Issue 12: ``capataz router --listen tls/...`` exited with "Missing TLS private key"."""
    port = free_port()
    missing = router({}, "--listen", f"tls/127.0.0.1:{port}")
    out = missing.communicate(timeout=60)[0].decode()  # it exits by itself
    assert missing.returncode == 1 and "CAPATAZ_ZENOH_TLS_KEY" in out and "Traceback" not in out
    env = {
        "CAPATAZ_ZENOH_TLS_CA": str(certs / "ca.pem"),
        "CAPATAZ_ZENOH_TLS_CERT": str(certs / "router.pem"),
        "CAPATAZ_ZENOH_TLS_KEY": str(certs / "router.key"),
    }
    process = router(env, "--listen", f"tls/127.0.0.1:{port}")
    try:
        wait_listening(process, port)
        client_env = {**env, "CAPATAZ_ZENOH_TLS_CERT": str(certs / "client.pem")}
        client_env["CAPATAZ_ZENOH_TLS_KEY"] = str(certs / "client.key")
        settings = TransportSettings.from_env(
            environ=client_env, mode="client", connect=(f"tls/127.0.0.1:{port}",), listen=()
        )
        with open_session(settings) as session:
            assert session.info.routers_zid()
    finally:
        stop(process)


@pytest.mark.zenoh
def test_user_password_authentication_from_a_credentials_file(tmp_path: Path) -> None:
    """Zenoh's usrpwd authentication, the router's dictionary in its config file and the client's
    ``user:password`` in CAPATAZ_ZENOH_USRPWD_FILE: right credentials connect, wrong ones are refused."""
    port = free_port()
    dictionary = tmp_path / "users.txt"
    dictionary.write_text("camera:right-password\n")
    path = write(
        tmp_path / "router.json5", {"transport": {"auth": {"usrpwd": {"dictionary_file": str(dictionary)}}}}
    )
    # the router authenticates itself too when it has a user; give it one the dictionary knows
    (tmp_path / "router-cred").write_text("camera:right-password\n")
    process = router(
        {"CAPATAZ_ZENOH_CONFIG": str(path), "CAPATAZ_ZENOH_USRPWD_FILE": str(tmp_path / "router-cred")},
        "--listen",
        f"tcp/127.0.0.1:{port}",
    )
    try:
        wait_listening(process, port)
        for password, ok in (("right-password", True), ("wrong", False)):
            cred = tmp_path / f"cred-{password}"
            cred.write_text(f"camera:{password}\n")
            settings = TransportSettings.from_env(
                environ={"CAPATAZ_ZENOH_USRPWD_FILE": str(cred)},
                mode="client",
                connect=(f"tcp/127.0.0.1:{port}",),
                listen=(),
                connect_timeout_ms=2000,
            )
            if ok:
                with open_session(settings) as session:
                    assert session.info.routers_zid()
            else:
                with pytest.raises(TransportError):
                    open_session(settings).close()
    finally:
        stop(process)
