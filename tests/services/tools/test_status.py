"""``capataz status`` on loopback: every member of a cluster started with ``capataz up`` is listed with its
health, host, UAV, uptime and counter rates, and every member answers a health query even with zenoh's
default consolidation (each on its own key); a degraded member shows why and its refusals; with nobody
there, one error line and exit 1."""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from common.members import MemberId, Role, Topology
from common.wire import keys
from services.runtime.service import HOST_NAME, ServiceRuntime
from services.runtime.transport import TransportSettings, open_session
from services.tools.cli import build_parser
from services.tools.secure import SecureProfile, participant_environment
from services.tools.status import Snapshot, status
from services.tools.up import ClusterSpec, HostSpec, LocalCluster
from tests.builders import small_cluster_file
from tests.zenoh_helpers import WAIT_S, hub, peer, wait_until

ROOT = Path(__file__).resolve().parents[3]
#: router, camera, master, a foreman and a worker on each of two hosts
SMALL_CLUSTER = small_cluster_file(hosts=2)
MEMBERS = {"router/router/0", "camera/camera/0", "master/master/0", "foreman/h1/0", "foreman/h2/0",
           "worker/h1/0", "worker/h2/0"}  # fmt: skip


def status_args(*argv: str) -> argparse.Namespace:
    return build_parser(("services.tools.status",)).parse_args(["status", *argv])


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[str]:
    """``capataz up`` of a small cluster (camera at 5 fps) as a user starts it; yields the router's endpoint
    and stops it with SIGINT, as a user does."""
    spec = tmp_path / "small.yml"
    spec.write_text(SMALL_CLUSTER)
    command = [sys.executable, "-m", "services.tools.cli", "up", "--cluster", str(spec), "--port", "0",
               "--duration", "0", "--fps", "5", "--logs", str(tmp_path / "logs"), "--open"]  # fmt: skip
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(process.stdout.readline, "")), daemon=True)  # type: ignore[union-attr]
    reader.start()
    try:
        assert wait_until(lambda: any(" up in " in line for line in lines) or process.poll() is not None, 120)
        up = next((line for line in lines if " up in " in line), None)
        assert up is not None, "".join(lines)
        yield re.search(r"router (tcp/127\.0\.0\.1:\d+)", up).group(1)  # type: ignore[union-attr]
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
        try:
            process.wait(60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        reader.join(5)
    assert process.returncode == 0, "".join(lines)[-3000:]


@pytest.mark.zenoh
def test_status_lists_every_member_of_a_capataz_up_cluster_with_health_and_rates(cluster: str) -> None:
    args = status_args("--connect", cluster, "--window", "2.5")
    snapshots: list[Snapshot] = []

    def complete() -> bool:
        """Every member with its health; the master's and camera's frame rates measured over a window."""
        snapshots.append(status(args, io.StringIO())[-1])
        members = snapshots[-1].members
        return (
            set(members) >= MEMBERS
            and members["master/master/0"].rates.get("frames_in", 0) > 0
            and members["camera/camera/0"].rates.get("frames_out", 0) > 0
        )

    assert wait_until(complete, 90, interval_s=0.5), snapshots[-1].document()
    members = snapshots[-1].members
    assert set(members) == MEMBERS
    for name, member in members.items():
        assert member.alive and member.state == "ok" and member.health is not None, name
        assert member.stats is not None and member.stats.host == HOST_NAME, name
        assert member.stats.uptime_s > 0, name
    assert members["master/master/0"].stats.uavs == ["uav0"]  # type: ignore[union-attr]
    assert members["camera/camera/0"].stats.uavs == ["uav0"]  # type: ignore[union-attr]
    assert members["worker/h1/0"].stats.uavs == []  # type: ignore[union-attr]
    assert members["camera/camera/0"].rates["frames_out"] > 0
    assert snapshots[-1].streams[keys.camera_key("uav0")].messages > 0
    rows = {row["member"]: row for row in (m.row() for m in members.values())}
    assert rows["master/master/0"]["health"] == "ok" and rows["master/master/0"]["rates /s"] != "-"

    # the CLI's table and JSON, as an operator and a script see them
    done = subprocess.run([sys.executable, "-m", "services.tools.cli", "status", "--connect", cluster],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert all(name in done.stdout for name in MEMBERS) and "members, 0 not ok" in done.stdout

    # regression: every member answers a health query with the default consolidation (1 of 12 did)
    with open_session(TransportSettings(connect=(cluster,))) as session:

        def answered() -> set[str]:
            replies = session.get(keys.HEALTH_ALL, timeout=5.0)
            return {str(r.ok.key_expr) for r in replies if r.ok is not None}

        ids = [MemberId.from_name(name) for name in MEMBERS]
        expected = {keys.health_key(m.role, m.node, m.index) for m in ids}
        assert wait_until(lambda: answered() == expected, WAIT_S, interval_s=0.5)


class Sick(ServiceRuntime):
    """A member that refuses inputs and says so in its health."""

    role = Role.WORKER

    def healthy(self) -> tuple[bool, str]:
        return False, f"degraded: {self.counters.get('malformed')} inputs refused in the last 5 s"

    def queue_depths(self) -> dict[str, int]:
        return {"jobs": 2}


@pytest.mark.zenoh
def test_a_degraded_member_shows_why_and_its_refusals() -> None:
    with hub() as endpoint:
        sick = Sick("h9", 3, peer(endpoint), stats_period_s=0.2)
        for _ in range(3):
            sick.counters.inc("malformed")
        runner = threading.Thread(target=sick.run, daemon=True)
        runner.start()
        try:
            assert sick.started.wait(WAIT_S)
            args = status_args("--connect", endpoint, "--window", "1", "--no-streams")
            out = io.StringIO()
            found: list[Snapshot] = []

            def seen() -> bool:
                found.append(status(args, out)[-1])
                member = found[-1].members.get("worker/h9/3")
                return member is not None and member.stats is not None and member.health is not None

            assert wait_until(seen, WAIT_S, interval_s=0.2)
            row = found[-1].members["worker/h9/3"].row()
            assert row["health"] == "DEGRADED"
            assert row["why"] == "degraded: 3 inputs refused in the last 5 s"
            assert row["refused"] == 3 and row["queues"] == "jobs=2"
            assert "DEGRADED" in out.getvalue() and "3 inputs refused" in out.getvalue()
        finally:
            sick.request_stop()
            runner.join(10)


@pytest.mark.zenoh
def test_status_with_nobody_there_is_one_line_and_exit_1() -> None:
    with hub() as endpoint:
        done = subprocess.run(
            [sys.executable, "-m", "services.tools.cli", "status", "--connect", endpoint, "--window", "0.5"],
            capture_output=True, text=True, cwd=ROOT, timeout=120, env={**os.environ},
        )  # fmt: skip
    assert done.returncode == 1, done.stderr
    errors = [line for line in done.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "no member answered" in errors[0] and "Traceback" not in done.stderr


@pytest.mark.zenoh
def test_status_watch_repeats_until_its_duration(capsys: pytest.CaptureFixture[str]) -> None:
    with hub() as endpoint:
        sick = Sick("h8", 0, peer(endpoint), stats_period_s=0.2)
        runner = threading.Thread(target=sick.run, daemon=True)
        runner.start()
        try:
            assert sick.started.wait(WAIT_S)
            snapshots = status(status_args("--connect", endpoint, "--watch", "--window", "0.5",
                                           "--duration", "2", "--json", "--no-streams"))  # fmt: skip
        finally:
            sick.request_stop()
            runner.join(10)
    assert len(snapshots) >= 2
    assert len(capsys.readouterr().out.strip().splitlines()) == len(snapshots)


@pytest.mark.zenoh
def test_every_member_answers_health_with_the_default_consolidation() -> None:
    """Regression: replies on the query's key (``capataz/health/**``) were merged to one (1 of 4 here)."""
    with hub() as endpoint:
        members = [Sick("h7", i, peer(endpoint)) for i in range(4)]
        runners = [threading.Thread(target=m.run, daemon=True) for m in members]
        for runner in runners:
            runner.start()
        try:
            assert all(m.started.wait(WAIT_S) for m in members)
            expected = {keys.health_key(Role.WORKER, "h7", i) for i in range(4)}
            with open_session(peer(endpoint)) as session:

                def answered() -> set[str]:
                    return {str(r.ok.key_expr) for r in session.get(keys.HEALTH_ALL, timeout=5.0) if r.ok}

                assert wait_until(lambda: answered() == expected, WAIT_S, interval_s=0.2)
        finally:
            for m in members:
                m.request_stop()
            for runner in runners:
                runner.join(10)


@pytest.mark.zenoh
def test_a_member_that_left_is_listed_as_gone_then_forgotten(monkeypatch: pytest.MonkeyPatch) -> None:
    from services.tools import status as status_module

    monkeypatch.setattr(status_module, "FORGET_S", 3.0)
    with hub() as endpoint, open_session(peer(endpoint)) as session:
        observer = status_module.ClusterObserver(session, None, timeout_s=2.0)
        leaving = Sick("h6", 0, peer(endpoint), stats_period_s=0.2)
        runner = threading.Thread(target=leaving.run, daemon=True)
        runner.start()
        try:
            assert leaving.started.wait(WAIT_S)
            never = threading.Event()
            states: list[str] = []

            def state() -> str:
                member = observer.snapshot(0.3, never).members.get("worker/h6/0")
                states.append("absent" if member is None else member.state)
                return states[-1]

            assert wait_until(lambda: state() == "DEGRADED", WAIT_S, interval_s=0.1)
            leaving.request_stop()
            runner.join(10)
            assert wait_until(lambda: state() == "absent", WAIT_S, interval_s=0.1), states
            assert "gone" in states  # its token went first, its stats were kept a while
        finally:
            leaving.request_stop()
            observer.close()


@pytest.mark.zenoh
def test_status_in_the_secure_profile_with_the_read_only_client_certificate(tmp_path: Path) -> None:
    """Mutual TLS and access control on every participant: the operator's ``client`` certificate may
    subscribe to stats and liveliness and query health, which is all status needs."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (needed to make the development certificates)")
    secure = SecureProfile.ensure(tmp_path / "secure")
    spec = ClusterSpec(name="s", topology=Topology.MASTER_WORKER, hosts=(HostSpec(name="h1", workers=1),))
    with LocalCluster(spec, tmp_path / "logs", secure=secure) as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members())
        env = {**os.environ, **participant_environment(secure, None, "client")}
        command = [sys.executable, "-m", "services.tools.cli", "status", "--json", "--no-streams",
                   "--connect", cluster.router, "--listen", "tls/127.0.0.1:0"]  # fmt: skip
        documents: list[dict[str, Any]] = []

        def listed() -> bool:
            done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=120, env=env)
            assert done.returncode in (0, 1), done.stderr
            documents.append(json.loads(done.stdout) if done.returncode == 0 else {"members": []})
            states = {m["member"]: m["state"] for m in documents[-1]["members"]}
            return states == dict.fromkeys(["router/router/0", "master/master/0", "worker/h1/0"], "ok")

        assert wait_until(listed, 120, interval_s=0.5), documents[-1]
    assert cluster.router.startswith("tls/")
