"""The cluster across separate network hosts: the master and the camera on one emulated host, a foreman and
its workers on another, each host with its own router; frames flow over the link, yaw comes back, none lost.
Needs root and ``ip``/``tc`` (skipped with the reason otherwise)."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.dispatch import SELF
from services.tools.cluster_file import ClusterSpec, HostSpec
from services.tools.netns import NetHarness, list_namespaces, new_prefix, unavailable_reason
from services.tools.netns_cluster import NetnsCluster, plan_for_cluster
from tests.zenoh_helpers import members_outweigh_master

pytestmark = [pytest.mark.zenoh, pytest.mark.slow]

FRAMES = 40


def test_master_and_camera_on_one_host_foreman_and_workers_on_another(tmp_path: Path) -> None:
    if (reason := unavailable_reason()) is not None:
        pytest.skip(reason)
    spec = ClusterSpec(name="net", hosts=(HostSpec(name="h1", workers=2),))
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
    # of a member that missed its deadline (its documented fallback, counted as a re-dispatch): on a loaded
    # host one 0.3 s stall is enough, so a master share is asserted to come with one
    members = got["members"]
    assert members_outweigh_master(members), members
    assert SELF not in members or got["redispatched"] > 0, got
    assert all("/h1/" in member for member in members if member != SELF), members
    assert all(code in (0, None) for name, code in codes.items() if not name.startswith("camera")), codes
    assert not set(plan.namespaces) & set(list_namespaces())
