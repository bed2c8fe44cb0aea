"""``capataz echo`` and ``capataz hz`` against a publisher of the test's own on loopback: echo prints each
message decoded, one line each, reports a sample that is not a capataz message on stderr, stops after
``--count`` and on SIGTERM (exit 0); hz counts every arrival and reports ros2-style interval figures."""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest

from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import YawEstimate
from services.runtime.transport import open_session
from services.tools.cli import build_parser
from services.tools.echo import echo
from services.tools.hz import RateWindow, hz
from tests.zenoh_helpers import WAIT_S, hub, matched, peer, wait_until

pytestmark = pytest.mark.zenoh

ROOT = Path(__file__).resolve().parents[3]


def parse(*argv: str) -> argparse.Namespace:
    return build_parser((f"services.tools.{argv[0]}",)).parse_args(list(argv))


def yaw(seq: int) -> YawEstimate:
    return YawEstimate(
        uav="uav0", seq=seq, stamp_s=0.05 * seq, delta_yaw_rad=0.01, yaw_rad=0.01 * seq, inlier_count=30,
        patch_count=40, confidence=0.9, low_confidence=False, method="patches",
    )  # fmt: skip


def publish_when_matched(endpoint: str, messages: list[Any], garbage: bool = False) -> threading.Thread:
    """A thread that publishes ``messages`` on uav0's yaw key once a subscriber is there."""

    def run() -> None:
        with open_session(peer(endpoint)) as session:
            publisher = session.declare_publisher(keys.yaw_key("uav0"))
            assert matched(publisher)
            if garbage:
                publisher.put(b"not a message", attachment=b"\xc1")
            for message in messages:
                payload, attachment = encode(message)
                publisher.put(payload, attachment=attachment)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_echo_prints_each_message_decoded_and_stops_after_count(capsys: pytest.CaptureFixture[str]) -> None:
    with hub() as endpoint:
        publisher = publish_when_matched(endpoint, [yaw(i) for i in range(8)], garbage=True)
        out = io.StringIO()
        result = echo(
            parse("echo", keys.yaw_key("uav0"), "--connect", endpoint, "--count", "5", "--json"), out
        )
        publisher.join(WAIT_S)
    lines = out.getvalue().splitlines()
    assert result == {"printed": 5, "malformed": 1, "dropped": 0}
    assert len(lines) == 5
    records = [json.loads(line) for line in lines]
    assert [r["fields"]["seq"] for r in records] == [0, 1, 2, 3, 4]
    assert all(r["key"] == keys.yaw_key("uav0") and r["type"] == "YawEstimate" for r in records)
    assert records[3]["fields"]["yaw_rad"] == pytest.approx(0.03)
    assert "not a capataz message" in capsys.readouterr().err


def test_echo_shows_arrays_as_their_shape_unless_small() -> None:
    import numpy as np

    from common.wire.messages import Frame
    from services.tools.echo import echo_line
    from services.tools.probe import Arrival

    frame = Frame(uav="uav0", seq=3, stamp_s=0.15, width=64, height=48, pixels=np.zeros((48, 64), np.uint8))
    payload, attachment = encode(frame)
    line, ok = echo_line(Arrival(0.0, keys.camera_key("uav0"), payload, attachment), as_json=False)
    assert ok and line.startswith("capataz/uav/uav0/camera Frame {")
    assert '"pixels":"<uint8 48x64>"' in line and '"seq":3' in line


def test_hz_counts_every_arrival_and_reports_interval_figures() -> None:
    with hub() as endpoint:
        rates = RateWindow(window=100, per_key=False, name=keys.yaw_key("uav0"))
        done = threading.Event()

        def publish_then_interrupt() -> None:
            publish_when_matched(endpoint, [yaw(i) for i in range(40)]).join(WAIT_S)
            wait_until(lambda: rates.total >= 40)
            done.set()
            os.kill(os.getpid(), signal.SIGINT)  # as ^C: hz stops cleanly

        thread = threading.Thread(target=publish_then_interrupt, daemon=True)
        thread.start()
        out = io.StringIO()
        args = parse("hz", keys.yaw_key("uav0"), "--connect", endpoint, "--every", "0.2", "--duration", "120")
        hz(args, out, rates)
        thread.join(WAIT_S)
    assert done.is_set() and rates.total == 40
    figures = rates.figures()[keys.yaw_key("uav0")]
    assert figures is not None and figures.messages == 40
    times = list(rates.arrivals[keys.yaw_key("uav0")])
    assert figures.mean_s == pytest.approx((times[-1] - times[0]) / 39)
    assert figures.min_s <= figures.mean_s <= figures.max_s
    last = out.getvalue().splitlines()[-1]  # the figures at the end (^C)
    assert last.startswith(f"{keys.yaw_key('uav0')}: average rate: ") and last.endswith("window: 40")


def test_echo_process_exits_0_on_sigterm() -> None:
    with hub() as endpoint, open_session(peer(endpoint)) as session:
        process = subprocess.Popen(
            [sys.executable, "-m", "services.tools.cli", "echo", keys.yaw_key("uav0"), "--connect", endpoint],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        )  # fmt: skip
        try:
            publisher = session.declare_publisher(keys.yaw_key("uav0"))
            assert matched(publisher)  # its subscriber is declared: it is running
            payload, attachment = encode(yaw(7))
            publisher.put(payload, attachment=attachment)
            process.send_signal(signal.SIGTERM)
            _stdout, stderr = process.communicate(timeout=WAIT_S)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
    assert process.returncode == 0, stderr
    assert "Traceback" not in stderr


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["hz", "k", "--window", "1"], "--window must be >= 2"),
        (["hz", "k", "--every", "0"], "--every must be > 0"),
        (["echo", "k", "--count", "-1"], "--count must be >= 0"),
        (["status", "--window", "0"], "--window must be > 0"),
        (["metrics", "--port", "70000"], "--port must be in 0..65535"),
        (["echo", "bad key//"], "KEY 'bad key//' is not a key expression"),
        (["hz", "capataz//x"], "KEY 'capataz//x' is not a key expression"),
    ],
)
def test_bad_options_give_one_line_and_exit_2(argv: list[str], fragment: str) -> None:
    done = subprocess.run([sys.executable, "-m", "services.tools.cli", *argv], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)  # fmt: skip
    assert done.returncode == 2, done.stderr
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and fragment in errors[0] and "Traceback" not in done.stderr
