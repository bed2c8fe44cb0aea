"""The cluster across separate network hosts: the master and the camera on one emulated host, a foreman and
its workers on another, each host with its own router; frames flow over the link, yaw comes back, none lost.
Needs root and ``ip``/``tc`` (skipped with the reason otherwise)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common.dispatch import SELF
from common.members import Topology
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.netns import NetHarness, list_namespaces, new_prefix, unavailable_reason
from services.tools.netns_cluster import NetnsCluster, plan_for_cluster
from tests.zenoh_helpers import members_outweigh_master

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 40


def test_master_and_camera_on_one_host_foreman_and_workers_on_another(tmp_path: Path) -> None:
    if (reason := unavailable_reason()) is not None:
        pytest.skip(reason)
    # members get 1 s (the frame's budget), not 0.3 s: a loaded CI host made a member miss 0.3 s twice in a
    # flight of the bench's same path (tests/services/tools/test_bench_dispatch.py), and the master computed
    # 60 % of it. The path across hosts is measured here; the fault path has its own tests
    spec = ClusterSpec(name="net", hosts=(HostSpec(name="h1", workers=2),), min_deadline_ms=1000.0)
    plan = plan_for_cluster(spec, new_prefix(), {"h1": 100_000_000})
    with NetHarness(plan) as net, NetnsCluster(spec, tmp_path / "logs", net) as cluster:
        cluster.start()
        cluster.wait_alive(cluster.expected_members() | {"router/ground/0", "router/h1/0"}, 90.0)
        yaw = cluster.agent("ground", ["yaw", "--count", str(FRAMES)], 120.0)
        yaw.wait_ready()
        cluster.start_camera(["--frames", str(FRAMES), "--fps", "10", "--in-flight", "1", "--no-sensors"])
        got = yaw.result(150.0)
        codes = cluster.stop()
    assert got["seqs"] == list(range(FRAMES)), f"lost: {sorted(set(range(FRAMES)) - set(got['seqs']))}"
    assert got["malformed"] == 0
    assert got["median_timings_ms"]["total"] > 0  # the master's frame-in to yaw-out time, per frame
    # the master only dispatches: the patches are computed across the link, on host h1. It takes the share
    # of a member that missed its deadline (its documented fallback, counted as a re-dispatch), so a master
    # share is asserted to come with one
    members = got["members"]
    assert members_outweigh_master(members), members
    assert SELF not in members or got["redispatched"] > 0, got
    assert all("/h1/" in member for member in members if member != SELF), members
    assert all(code in (0, None) for name, code in codes.items() if not name.startswith("camera")), codes
    assert not set(plan.namespaces) & set(list_namespaces())


#: issue 29's heavy workload: 1920x1080 at level 0, 16 x 12 patches of 128 px (a share travels as a band of
#: the frame: 2.1 MB a whole frame, against 3.1 MB of crops)
HEAVY_MASTER_ARGS = ("--grid", "16x12", "--patch-size", "128", "--pyramid-level", "0")
HEAVY_FRAMES = 36


def test_the_balancer_moves_shares_away_from_a_host_behind_a_thin_link(tmp_path: Path) -> None:
    """Two member hosts, one foreman and one worker each: h1 behind 100 Mbit, h2 behind 20 Mbit. Each half of
    a frame (a band of 1.1 MB) takes about 0.09 s to h1 and 0.43 s to h2. Once the foremen have earned
    credit (10 consistent frames), h2 gets less than h1: h1 is held at half the frame by the trust cap and the
    dispatcher computes what h2 would finish last with (before the fix both kept half: the regression test
    is :func:`tests.common.dispatch.test_trust.
    test_a_capped_fast_members_overflow_goes_to_the_dispatcher_not_to_a_slow_member_regression`). Nothing
    is lost."""
    if (reason := unavailable_reason()) is not None:
        pytest.skip(reason)
    spec = ClusterSpec(
        name="thin",
        topology=Topology.MASTER_FOREMAN_WORKER,
        hosts=(HostSpec(name="h1", workers=1), HostSpec(name="h2", workers=1)),
    )
    plan = plan_for_cluster(spec, new_prefix(), {"h1": 100_000_000, "h2": 20_000_000})
    with (
        NetHarness(plan) as net,
        NetnsCluster(spec, tmp_path / "logs", net, master_args=HEAVY_MASTER_ARGS) as cluster,
    ):
        cluster.start()
        cluster.wait_alive(cluster.expected_members(), 90.0)
        yaw = cluster.agent("ground", ["yaw", "--count", str(HEAVY_FRAMES)], 240.0)
        yaw.wait_ready()
        cluster.start_camera(["--frames", str(HEAVY_FRAMES), "--fps", "1", "--in-flight", "1", "--no-sensors",
                              "--resolution", "1920x1080"])  # fmt: skip
        got = yaw.result(260.0)
        codes = cluster.stop()
    assert got["seqs"] == list(range(HEAVY_FRAMES)), (
        f"lost: {sorted(set(range(HEAVY_FRAMES)) - set(got['seqs']))}"
    )
    late = [members for seq, members, _ in got["frames"] if seq >= HEAVY_FRAMES - 12]
    n_patches = 16 * 12

    def share(host: str) -> float:
        return float(
            np.median([sum(n for m, n in ms.items() if f"/{host}/" in m and ">" not in m) for ms in late])
        )

    thin, wide = share("h2") / n_patches, share("h1") / n_patches
    # here: 0.31-0.33 and 0.50 (before the fix 0.50 and 0.50, a frame 715 ms against 445-455 ms now); 0.25
    # and 0.50 on a 3x faster CPU with links that keep their wire time (a frame 252-352 ms). A
    # loaded host slows the members' compute while the link stays as slow, so the balanced share of the thin
    # host rises towards the other's: 0.42 in a CI run with a benchmark beside the suite (3 test processes
    # and the benchmark on 2 cores). The bound keeps the bug's 0.50 and 0.50 out with that margin.
    assert thin <= 0.45, (thin, wide, late[-3:])
    assert wide >= 0.45 and wide >= thin + 0.05, (thin, wide, late[-3:])
    assert all(code in (0, None) for name, code in codes.items() if not name.startswith("camera")), codes
    assert not set(plan.namespaces) & set(list_namespaces())
