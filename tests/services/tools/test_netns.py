"""Separate network hosts on one machine: namespaces, links, rates and routers the harness makes and always
removes. Needs root and ``ip``/``tc`` (skipped with the reason otherwise)."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.netplan import BRIDGE, HOST_INTERFACE, make_plan
from services.tools.cluster_file import ClusterError, ClusterSpec, HostSpec
from services.tools.netns import (
    NetHarness,
    cleanup_stale,
    link_bytes_per_frame,
    list_namespaces,
    new_prefix,
    run,
    unavailable_reason,
)
from services.tools.netns_cluster import NetnsCluster, plan_for_cluster
from tests.zenoh_helpers import wait_until

pytestmark = [pytest.mark.zenoh]

ROUTERS_ONLY = ClusterSpec(name="net", hosts=(HostSpec(name="h1", workers=0),))
TEN_MB = 10_000_000


@pytest.fixture(scope="module")
def netns() -> None:
    if (reason := unavailable_reason()) is not None:
        pytest.skip(reason)


@pytest.fixture
def untouched_root() -> Iterator[None]:
    """This process's namespaces and the root namespace's links are the same after the test as before it
    (only its own: a netns test in the other test process makes and removes namespaces meanwhile, which the
    stress run of the suite caught)."""

    def own() -> set[str]:
        return {n for n in list_namespaces() if n.startswith(f"cz{os.getpid()}x")}

    before_ns, before_links = own(), _root_links()
    yield
    assert own() == before_ns
    assert _root_links() == before_links


def _root_links() -> list[str]:
    out = subprocess.run(["ip", "-o", "link", "show"], capture_output=True, text=True, check=True).stdout
    return sorted(line.split(":")[1].strip() for line in out.splitlines())


def test_a_put_in_one_host_reaches_a_subscriber_in_another_and_each_router_runs_on_its_hosts_cpus(
    netns: None, untouched_root: None, tmp_path: Path
) -> None:
    # the camera and the ground's router on the first CPU, h1 on the last: h1's router runs on h1's CPUs
    # like its foreman and workers (it ran on the camera's before)
    cores = sorted(os.sched_getaffinity(0))
    hosts = (HostSpec(name="h1", workers=0, cpus=str(cores[-1])), HostSpec(name="h2", workers=0))
    spec = ClusterSpec(name="net3", hosts=hosts, aux_cpus=str(cores[0]))
    plan = plan_for_cluster(spec, new_prefix())
    with NetHarness(plan) as net, NetnsCluster(spec, tmp_path, net) as cluster:
        assert set(plan.namespaces) <= set(list_namespaces())
        cluster.start_router()
        routers = {f"router/{h.name}/0" for h in plan.hosts}
        cluster.wait_alive(routers)  # seen from the ground host: the three routers are one mesh
        assert os.sched_getaffinity(cluster.processes["router/h1/0"].pid) == {cores[-1]}
        assert os.sched_getaffinity(cluster.processes["router/ground/0"].pid) == {cores[0]}
        with pytest.raises(ClusterError, match="worker/nowhere/0"):
            cluster.wait_alive(routers | {"worker/nowhere/0"}, timeout_s=1.0)
        sub = cluster.agent("h2", ["sub", "test/net/hello"])
        sub.wait_ready()
        put = cluster.agent("h1", ["put", "test/net/hello", "across the hub"])
        assert put.result(45.0) == {"matched": True}
        assert sub.result(45.0) == {"received": 1, "text": "across the hub"}


def _reply_seconds(tmp_path: Path, rate_bit_s: int | None, size: int = TEN_MB) -> float:
    """The time of one query for ``size`` bytes that h1 (behind a ``rate_bit_s`` link) serves the ground."""
    plan = plan_for_cluster(ROUTERS_ONLY, new_prefix(), {"h1": rate_bit_s})
    with NetHarness(plan) as net, NetnsCluster(ROUTERS_ONLY, tmp_path, net) as cluster:
        cluster.start_router()
        server = cluster.agent("h1", ["serve", "test/net/big", "--size", str(size)], 120.0)
        server.wait_ready()
        before = net.link_bytes()
        got = cluster.agent("ground", ["get", "test/net/big"], 120.0).result(150.0)
        assert server.result(30.0) == {"served": 1}
        after = net.link_bytes()
    assert got["bytes"] == size
    # the reply crossed both links: sent by h1 on its link, received by the ground on its own
    assert after["h1"][1] - before["h1"][1] >= size
    assert after["ground"][0] - before["ground"][0] >= size
    return float(got["seconds"])


def test_a_20_mbit_link_makes_a_10_mb_transfer_slower(
    netns: None, untouched_root: None, tmp_path: Path
) -> None:
    unlimited_s = _reply_seconds(tmp_path / "unlimited", None)
    limited_s = _reply_seconds(tmp_path / "limited", 20_000_000)
    # the token bucket cannot pass 80 Mbit in less than 4 s (less its 16 KiB bursts); the unlimited veth
    # took 0.05 s here: a ratio of 4 leaves a wide margin for a loaded host
    assert limited_s >= 0.9 * TEN_MB * 8 / 20_000_000
    assert limited_s > 4 * unlimited_s, (limited_s, unlimited_s)


def test_a_job_after_an_idle_link_takes_its_wire_time_regression(
    netns: None, untouched_root: None, tmp_path: Path
) -> None:
    # a 1080p share's job (260 kB) on a 100 Mbit link that was idle: the wire needs 20.8 ms. A token bucket
    # holding 10 ms of the rate let it cross in 11.9 ms, which flattered every distributed path by 9 ms a
    # frame. A loaded host can only make it slower: the bound is a floor.
    size, rate = 260_000, 100_000_000
    seconds = _reply_seconds(tmp_path, rate, size)
    assert seconds >= 0.85 * size * 8 / rate, seconds


def _shown(*argv: str) -> str:
    return subprocess.run(list(argv), capture_output=True, text=True, timeout=30, check=True).stdout


def test_a_rated_link_is_shaped_inside_the_hub_not_on_the_host_s_own_end_regression(
    netns: None, untouched_root: None
) -> None:
    # a bucket on the host's end ran on the host's CPU: about 100 timer interrupts and hand-overs for a 1080p
    # frame's job, inside the master's own share (its patches 8-50 % slower than alone); a NIC shapes its
    # wire in its own silicon, so both buckets sit in the hub, whose CPUs are the other hosts'
    plan = make_plan(new_prefix(), ["a", "b"], {"a": 5_000_000})
    a, b, hub = plan.host("a"), plan.host("b"), plan.hub_namespace
    with NetHarness(plan):
        own_end = _shown("tc", "-n", a.namespace, "qdisc", "show", "dev", HOST_INTERFACE)
        uplink = _shown("tc", "-n", hub, "qdisc", "show", "dev", a.uplink_interface)
        downlink = _shown("tc", "-n", hub, "qdisc", "show", "dev", a.hub_interface)
        up = _shown("tc", "-n", hub, "filter", "show", "dev", a.hub_interface, "ingress")
        down = _shown("tc", "-n", hub, "filter", "show", "dev", a.uplink_interface, "ingress")
        ports = _shown("ip", "-n", hub, "-o", "link", "show", "master", BRIDGE)
    assert "tbf" not in own_end, own_end
    assert "tbf" in uplink and "rate 5Mbit" in uplink, uplink
    assert "tbf" in downlink and "rate 5Mbit" in downlink, downlink
    assert f"Redirect to device {a.uplink_interface}" in up, up
    assert f"Redirect to device {a.hub_interface}" in down, down
    bridged = {line.split(":")[1].strip().split("@")[0] for line in ports.splitlines()}
    assert bridged == {a.bridge_port, b.hub_interface}  # the unrated link joins the bridge directly


def test_an_exception_inside_removes_everything(netns: None, untouched_root: None) -> None:
    plan = make_plan(new_prefix(), ["a", "b"], {"b": 1_000_000})
    with pytest.raises(RuntimeError, match="boom"), NetHarness(plan):
        assert set(plan.namespaces) <= set(list_namespaces())
        raise RuntimeError("boom")
    assert not set(plan.namespaces) & set(list_namespaces())


HOLDER = """
import sys, time
from common.netplan import make_plan
from services.tools.netns import NetHarness
with NetHarness(make_plan(sys.argv[1], ["a", "b"])):
    print("up", flush=True)
    time.sleep(120)
"""


def test_sigterm_removes_everything(netns: None, untouched_root: None) -> None:
    prefix = new_prefix()
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, prefix], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "up"
        assert any(ns.startswith(prefix + "-") for ns in list_namespaces())
        holder.send_signal(signal.SIGTERM)
        assert holder.wait(30.0) == 128 + signal.SIGTERM
    finally:
        holder.kill()
        holder.wait()
    assert not [ns for ns in list_namespaces() if ns.startswith(prefix + "-")]


def test_cleanup_stale_removes_only_namespaces_of_dead_owners(
    netns: None, untouched_root: None, capsys: pytest.CaptureFixture[str]
) -> None:
    gone = subprocess.Popen(["true"])
    gone.wait()
    assert wait_until(lambda: not os.path.exists(f"/proc/{gone.pid}"), 10.0)
    stale, live = f"cz{gone.pid}x0-h1", f"{new_prefix()}-h1"
    for namespace in (stale, live):
        subprocess.run(["ip", "netns", "add", namespace], check=True)
    try:
        removed = cleanup_stale()
        assert stale in removed and live not in removed
        assert live in list_namespaces() and stale not in list_namespaces()
        subprocess.run(["ip", "netns", "add", stale], check=True)  # and through ``capataz netns cleanup``
        assert run(argparse.Namespace(netns_command="cleanup", prefix=f"cz{gone.pid}x")) == 0
        assert capsys.readouterr().out.strip() == f"removed 1 namespace(s): {stale}"
        assert live in list_namespaces() and stale not in list_namespaces()
    finally:
        for namespace in (stale, live):
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True)


def test_a_host_process_sees_only_its_address_and_runs_on_its_cpu_set(
    netns: None, untouched_root: None
) -> None:
    cpu = str(max(os.sched_getaffinity(0)))
    plan = make_plan(new_prefix(), ["a", "b"], cpus={"a": cpu})
    probe = (
        "import os, subprocess; print(sorted(os.sched_getaffinity(0))); "
        f"print(open('/sys/class/net/{HOST_INTERFACE}/queues/rx-0/rps_cpus').read().strip()); "
        "print(subprocess.run(['ip', '-o', '-4', 'addr'], capture_output=True, text=True).stdout)"
    )
    with NetHarness(plan) as net:
        argv = net.exec_argv("a", [sys.executable, "-c", probe])
        out = subprocess.run(argv, capture_output=True, text=True, timeout=30, check=True).stdout
        # what b sends into the hub is forwarded on a's CPU (the only pinned host), not on b's sending CPU
        hub_steering = {
            name: subprocess.run(
                ["ip", "netns", "exec", plan.hub_namespace, "cat",
                 f"/sys/class/net/{plan.host(name).hub_interface}/queues/rx-0/rps_cpus"],
                capture_output=True, text=True, timeout=30, check=True,
            ).stdout.strip().replace(",", "")
            for name in ("a", "b")
        }  # fmt: skip
    assert {k: int(v, 16) for k, v in hub_steering.items()} == {"a": 0, "b": 1 << int(cpu)}
    affinity, steering, addresses = out.split("\n", 2)
    assert affinity == f"[{cpu}]"
    # what arrives on its link is processed on its CPU too, as on a machine of its own
    assert int(steering.replace(",", ""), 16) == 1 << int(cpu)
    assert plan.host("a").address in addresses and plan.host("b").address not in addresses
    assert "127.0.0.1" in addresses and len(addresses.strip().splitlines()) == 2  # lo and its link only


def test_bytes_per_frame_are_each_links_counter_changes_over_the_frames() -> None:
    before = {"ground": (1_000, 2_000), "h1": (0, 0)}
    after = {"ground": (3_000, 42_000), "h1": (40_000, 2_000)}
    links = link_bytes_per_frame(before, after, 20)
    assert links == {
        "ground": {"rx_bytes_per_frame": 100.0, "tx_bytes_per_frame": 2_000.0},
        "h1": {"rx_bytes_per_frame": 2_000.0, "tx_bytes_per_frame": 100.0},
    }
    assert link_bytes_per_frame(before, after, 0)["h1"]["rx_bytes_per_frame"] == 40_000.0  # no frame: one


def test_a_machine_whose_tc_cannot_redirect_is_a_reason_to_skip_and_the_probe_is_removed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A kernel without ``tc``'s ingress redirect cannot shape a link in the hub: the harness says so in one
    line (tests skip with it) instead of failing halfway through making a plan's links."""
    import services.tools.netns as netns_module

    calls: list[list[str]] = []

    def fake_run(argv: list[str]) -> str:
        calls.append(list(argv))
        if "mirred" in argv:
            raise netns_module.NetnsError("tc filter add ...: Error: TC action not found")
        return ""

    monkeypatch.setattr(netns_module.os, "geteuid", lambda: 0)
    monkeypatch.setattr(netns_module.shutil, "which", lambda tool: f"/usr/sbin/{tool}")
    monkeypatch.setattr(netns_module, "_run", fake_run)
    reason = unavailable_reason()
    assert reason is not None and reason.startswith("tc cannot shape a link here"), reason
    added = [c[-1] for c in calls if c[:3] == ["ip", "netns", "add"]]
    deleted = [c[-1] for c in calls if c[:3] == ["ip", "netns", "del"]]
    assert len(added) == 1 and deleted == added
