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
    # the master only dispatches: every patch was computed across the link, on host h1
    assert SELF not in got["members"] and sum(got["members"].values()) > 0, got["members"]
    assert all("/h1/" in member for member in got["members"]), got["members"]
    assert all(code in (0, None) for name, code in codes.items() if not name.startswith("camera")), codes
    assert not set(plan.namespaces) & set(list_namespaces())
