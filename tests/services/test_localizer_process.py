"""``capataz localizer`` as a process: joins on loopback, answers liveliness, stops cleanly on SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest
import zenoh

from common import keys
from services.runtime.transport import TransportSettings, open_session
from services.up import free_port

pytestmark = pytest.mark.zenoh


def test_localizer_process_stops_cleanly_on_sigterm() -> None:
    port = free_port()
    env = dict(os.environ, CAPATAZ_ZENOH_MULTICAST="0")
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.cli",
            "localizer",
            "--listen",
            f"tcp/127.0.0.1:{port}",
            "--particles",
            "20",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    alive = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            alive.set()

    try:
        client = TransportSettings(listen=("tcp/127.0.0.1:0",), connect=(f"tcp/127.0.0.1:{port}",))
        with open_session(client) as session:
            watcher = session.liveliness().declare_subscriber(
                keys.alive_role(keys.Role.LOCALIZER), on_token, history=True
            )
            assert alive.wait(30.0), "the localizer never declared itself alive"
            watcher.undeclare()
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=10.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, output.decode(errors="replace")
    assert b"stopped" in output
