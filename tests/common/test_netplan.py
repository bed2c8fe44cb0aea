"""The network plan: unique namespaces and addresses, rates and CPU sets where they were asked for."""

from __future__ import annotations

import ipaddress

import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.netplan import (
    MIN_RATE_BIT_S,
    ROUTER_PORT,
    NetPlanError,
    cpu_mask,
    make_plan,
    owner_pid,
    tbf_burst_bytes,
)

names = st.lists(st.from_regex(r"[a-z][a-z0-9_.-]{0,12}", fullmatch=True).filter(lambda n: n != "hub"),
                 min_size=1, max_size=40, unique=True)  # fmt: skip


@given(names, st.integers(1, 99999))
def test_every_host_has_its_own_namespace_and_private_address(hosts: list[str], pid: int) -> None:
    plan = make_plan(f"cz{pid}", hosts)
    assert [h.name for h in plan.hosts] == hosts
    assert len(set(plan.namespaces)) == len(hosts) + 1
    assert all(ns.startswith(f"cz{pid}-") and owner_pid(ns) == pid for ns in plan.namespaces)
    addresses = [ipaddress.ip_address(h.address) for h in plan.hosts]
    assert len(set(addresses)) == len(hosts)
    assert all(a in ipaddress.ip_network("10.231.0.0/24") and a.is_private for a in addresses)
    assert len({h.hub_interface for h in plan.hosts}) == len(hosts)
    assert all(len(h.hub_interface) <= 15 for h in plan.hosts)  # Linux interface names


@given(names)
def test_routers_form_a_mesh_each_dialling_only_earlier_ones(hosts: list[str]) -> None:
    plan = make_plan("cz1", hosts)
    links = {frozenset((h.router_endpoint, e)) for h in plan.hosts for e in plan.routers_before(h.name)}
    assert len(links) == len(hosts) * (len(hosts) - 1) // 2
    first = plan.hosts[0]
    assert plan.routers_before(first.name) == ()
    assert first.router_endpoint == f"tcp/{first.address}:{ROUTER_PORT}"


@given(st.integers(MIN_RATE_BIT_S, 10**11))
def test_burst_holds_a_full_segment_and_at_most_one_ms_beyond_it(rate: int) -> None:
    burst = tbf_burst_bytes(rate)
    assert burst >= 16 * 1024
    assert burst * 8 >= rate // 1000 - 8
    # what an idle bucket lets cross at once: never more than 1 ms of the wire's time over 16 KiB
    assert burst <= max(16 * 1024, rate // 8 // 1000)


def test_rates_and_cpus_go_to_their_hosts() -> None:
    plan = make_plan("cz7x2", ["a", "b"], {"b": 20_000_000}, {"a": "0"})
    assert (plan.host("a").rate_bit_s, plan.host("b").rate_bit_s) == (None, 20_000_000)
    assert (plan.host("a").cpus, plan.host("b").cpus) == ("0", None)
    assert plan.hub_namespace == "cz7x2-hub"


@pytest.mark.parametrize(
    ("prefix", "hosts", "rates"),
    [
        ("net1", ["a"], {}),  # not a harness prefix
        ("cz1", [], {}),
        ("cz1", ["a", "a"], {}),
        ("cz1", ["hub"], {}),
        ("cz1", ["a b"], {}),
        ("cz1", ["a"], {"b": 1_000_000}),
        ("cz1", ["a"], {"a": 1000}),
    ],
)
def test_bad_plans_are_refused(prefix: str, hosts: list[str], rates: dict[str, int]) -> None:
    with pytest.raises(NetPlanError):
        make_plan(prefix, hosts, rates)


def test_owner_pid_only_for_harness_names() -> None:
    assert owner_pid("cz42x3-h1") == 42
    assert owner_pid("cz42-hub") == 42
    assert owner_pid("docker-1") is None
    assert owner_pid("cz42") is None
    assert owner_pid("czx-h1") is None


@given(st.sets(st.integers(0, 63), min_size=1, max_size=10))
def test_a_cpu_lists_mask_has_exactly_its_cpus(cpus: set[int]) -> None:
    listed = ",".join(str(c) for c in sorted(cpus))
    assert cpu_mask(listed) == sum(1 << c for c in cpus)
    low, high = min(cpus), max(cpus)
    assert cpu_mask(f"{low}-{high}") == sum(1 << c for c in range(low, high + 1))


@pytest.mark.parametrize("cpus", ["", "a", "3-1", "-1", "0,,1", "2048"])
def test_a_cpu_list_that_is_not_one_is_refused(cpus: str) -> None:
    with pytest.raises(NetPlanError, match="CPU list"):
        cpu_mask(cpus)
