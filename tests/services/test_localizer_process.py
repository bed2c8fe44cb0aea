"""``capataz localizer`` as a process: joins on loopback, answers liveliness, stops cleanly on SIGTERM."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading

import pytest
import zenoh

from common.members import Role
from common.wire import keys
from services.runtime.transport import open_session
from tests.zenoh_helpers import WAIT_S, hub, peer

pytestmark = pytest.mark.zenoh


def test_localizer_process_stops_cleanly_on_sigterm() -> None:
    with hub() as endpoint:
        _stops_cleanly_on_sigterm(endpoint)


def _stops_cleanly_on_sigterm(endpoint: str) -> None:
    env = dict(os.environ, CAPATAZ_ZENOH_MULTICAST="0")
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.tools.cli",
            "localizer",
            "--connect",
            endpoint,
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
        with open_session(peer(endpoint)) as session:
            watcher = session.liveliness().declare_subscriber(
                keys.alive_role(Role.LOCALIZER), on_token, history=True
            )
            assert alive.wait(WAIT_S), "the localizer never declared itself alive"
            watcher.undeclare()
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=10.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, output.decode(errors="replace")
    assert b"stopped" in output
