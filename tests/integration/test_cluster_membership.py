"""Membership through real processes: a joiner gets a share within 5 frames; with every worker gone the
master keeps publishing yaw alone (master-worker topology, the paper's baseline)."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest

from common.dispatch import SELF
from services.runtime.transport import open_session
from services.tools.observe import YawCollector
from services.tools.up import LocalCluster
from tests.integration.cluster_helpers import two_by_two
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]


def test_joiner_gets_a_share_within_five_frames_and_master_computes_alone_without_workers(
    tmp_path: Path,
) -> None:
    spec = two_by_two(topology="master-worker", workers=1)
    with LocalCluster(spec, tmp_path / "logs") as cluster:
        cluster.start_router()
        cluster.start_worker(spec.hosts[0], 0)
        cluster.start_master()
        cluster.wait_alive({"master/master/0", "worker/h1/0"})
        with open_session(cluster.observer_transport()) as session:
            collector = YawCollector(session, spec.uav)
            cluster.start_camera(["--frames", "400", "--fps", "25", "--in-flight", "1", "--no-sensors"])
            assert wait_until(lambda: collector.newest() >= 20, 60.0)
            assert all(set(e.members) == {"worker/h1/0"} for s, e in collector.estimates.items() if s >= 3)

            cluster.start_worker(spec.hosts[1], 0)  # the joiner
            cluster.wait_alive({"worker/h2/0"})
            joined_at = collector.newest()
            assert wait_until(lambda: collector.newest() >= joined_at + 6, 30.0)
            first = min(s for s, e in collector.estimates.items() if "worker/h2/0" in e.members)
            print(f"\njoiner: first share {first - joined_at} frame(s) after its liveliness token was seen")
            assert first - joined_at <= 5, f"joiner got work {first - joined_at} frames after it joined"

            for name in ("worker/h1/0", "worker/h2/0"):
                cluster.signal(name, signal.SIGKILL)
            gone_at = collector.newest()
            assert wait_until(lambda: collector.newest() >= gone_at + 20, 30.0), "master stopped publishing"
            alone = [collector.estimates[s] for s in range(gone_at + 5, gone_at + 20)]
            print(f"no workers: {collector.newest() - gone_at} more frames with yaw, by the master alone")
            assert all(set(e.members) == {SELF} and e.members[SELF] == e.patch_count for e in alone)
            seqs = sorted(collector.estimates)
            assert seqs == list(range(seqs[0], seqs[-1] + 1)), "a frame without yaw"
            collector.close()


def test_two_uav_streams_share_the_workers(tmp_path: Path) -> None:
    spec = two_by_two(topology="master-worker", workers=2)
    with LocalCluster(spec, tmp_path / "logs") as cluster:
        cluster.start_router()
        for i in range(2):
            cluster.start_worker(spec.hosts[0], i)
        for i, uav in enumerate(("uav0", "uav1")):
            cluster.spawn(
                f"master/m/{i}",
                [
                    "master",
                    *cluster.transport_args(),
                    "--node",
                    "m",
                    "--index",
                    str(i),
                    "--uav",
                    uav,
                    "--topology",
                    "master-worker",
                ],
            )
        cluster.wait_alive({"master/m/0", "master/m/1", "worker/h1/0", "worker/h1/1"})
        with open_session(cluster.observer_transport()) as session:
            collectors = [YawCollector(session, uav) for uav in ("uav0", "uav1")]
            cluster.spawn(
                "camera/camera/0",
                [
                    "camera",
                    *cluster.transport_args(),
                    "--uav",
                    "uav0",
                    "--uav",
                    "uav1",
                    "--frames",
                    "60",
                    "--fps",
                    "10",
                    "--in-flight",
                    "1",
                    "--no-sensors",
                ],
            )
            assert all(c.wait_for(60, 60.0) for c in collectors)
            first, second = (c.estimates for c in collectors)
            # the same frames on both streams: the same yaw, each stream computed by both workers
            assert all(first[k].yaw_rad == second[k].yaw_rad for k in range(60))
            # the master computes a share itself only for a member that missed its deadline (on a busy host
            # one did at frame 30 in two runs of eight; a fresh-clone CI on a loaded 2-core host left 38 of
            # 60 frames to both workers alone): most frames are both workers' alone. The flight is paced at
            # 10 fps: a miss suspends the member for 1 s, which at full speed (--fps 0) was 20 frames or
            # more, so two misses left 25 of 60 (a loaded host, the suite's other worker running clusters)
            # and 10 at this pace
            workers = {"worker/h1/0", "worker/h1/1"}
            for estimates in (first, second):
                assert all(set(estimates[k].members) <= workers | {SELF} for k in range(60))
                assert sum(set(estimates[k].members) == workers for k in range(60)) >= 30
            for collector in collectors:
                collector.close()
