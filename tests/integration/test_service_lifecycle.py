"""Every service: liveliness token, health answer, stats, and a clean exit (code 0) on SIGTERM and SIGINT."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from common.wire import keys
from common.wire.codec import decode
from common.wire.messages import Health, Stats
from services.runtime.transport import open_session, zbytes
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]


def test_services_declare_liveliness_answer_health_publish_stats_and_stop_cleanly(tmp_path: Path) -> None:
    spec = two_by_two(workers=1)
    with LocalCluster(spec, tmp_path / "logs") as cluster:
        cluster.start()
        cluster.start_camera(["--frames", "20", "--fps", "2", "--loop", "--no-sensors"])
        members = cluster.expected_members() | {"camera/camera/0"}
        cluster.wait_alive(members)
        with open_session(cluster.observer_transport()) as session:
            stats: dict[str, Stats] = {}
            sub = session.declare_subscriber(
                keys.STATS_ALL,
                lambda s: stats.__setitem__(
                    str(s.key_expr), decode(zbytes(s.payload), zbytes(s.attachment), Stats)
                ),
            )
            for name in sorted(members):
                role, node, index = name.split("/")
                replies: list = []
                deadline = time.monotonic() + 10.0
                while not replies and time.monotonic() < deadline:  # a new session learns routes first
                    replies = list(session.get(keys.health_key(role, node, int(index)), timeout=5.0))
                assert replies and replies[0].ok is not None, name
                health = decode(zbytes(replies[0].ok.payload), zbytes(replies[0].ok.attachment), Health)
                assert health.ok and (health.role, health.node, health.index) == (role, node, int(index))
            wanted = {keys.stats_key(*n.split("/")[:2], int(n.split("/")[2])) for n in members}
            deadline = time.monotonic() + 10.0
            while not wanted <= set(stats) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert wanted <= set(stats)
            # the callback's hand-off (inbox) and the frame queue
            assert stats[keys.stats_key("master", "master", 0)].queue_depths.keys() == {"inbox", "frames"}
            sub.undeclare()
        exit_s = {}
        for i, name in enumerate(sorted(members)):
            process = cluster.processes[name]
            t0 = time.monotonic()
            cluster.signal(name, signal.SIGTERM if i % 2 else signal.SIGINT)
            process.wait(30.0)  # a bound, not a speed claim: the host may be busy
            exit_s[name] = time.monotonic() - t0
            assert process.returncode == 0, f"{name} exited with {process.returncode}"
            log = (tmp_path / "logs" / f"{name.replace('/', '_')}.log").read_text(errors="replace")
            assert f"{name}: stopped" in log, f"{name} did not take the clean shutdown path"
        # reported, not asserted (wall-clock): about 0.1-0.6 s each on an idle host
        print(f"\nexit after signal: max {max(exit_s.values()):.2f} s, {exit_s}")
