"""The plan of emulated network hosts on one machine: which namespaces, addresses, links and rates.

A pure value object (no ``ip`` calls here): :func:`make_plan` names one Linux network namespace per host
(``<prefix>-<host>``) plus a hub namespace (``<prefix>-hub``) holding the bridge every host's link joins,
gives each host a private address ``10.231.0.<i>`` that exists only inside its namespace, and an optional
link rate (bit/s, a token bucket for each direction of the link, both inside the hub). The harness that
carries it out is :mod:`services.tools.netns`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from common.errors import CapatazError

#: a harness prefix: ``cz`` then the owner's pid, optionally ``x<n>`` for several harnesses in one process
PREFIX_PATTERN = re.compile(r"^cz(?P<pid>[0-9]{1,10})(x[0-9]{1,4})?$")
HOST_PATTERN = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
#: the private /24 of every plan (each plan lives in namespaces of its own, so plans never meet)
SUBNET = "10.231.0"
#: the interface of a host's end of its link, inside the host's namespace
HOST_INTERFACE = "cz0"
#: the bridge inside the hub namespace
BRIDGE = "czbr"
#: the port of each host's router, on the host's address
ROUTER_PORT = 7447
#: the smallest link rate accepted (a token bucket below this is not a link, it is a cut)
MIN_RATE_BIT_S = 64_000
MAX_HOSTS = 200


class NetPlanError(CapatazError):
    """A network plan is invalid (prefix, host names, rates)."""


@dataclass(frozen=True)
class NetHost:
    """One emulated host: its namespace, its address, its link to the hub and the link's rate."""

    name: str
    #: 1-based position in the plan; the host's address ends in it
    index: int
    namespace: str
    address: str
    #: the link's rate in bit/s in both directions; None = unlimited (veth speed)
    rate_bit_s: int | None
    #: taskset CPU list of the host's processes; None = not pinned
    cpus: str | None

    @property
    def hub_interface(self) -> str:
        """The hub's end of the host's link (inside the hub namespace)."""
        return f"czp{self.index}"

    @property
    def uplink_interface(self) -> str:
        """Inside the hub, where a rated link's uplink is shaped: what the host sends is redirected from
        :attr:`hub_interface` to this interface's token bucket, whose peer (:attr:`bridge_port`) joins the
        bridge. The bucket runs on the hub's CPUs, as a NIC's does in its own silicon, not on the host's."""
        return f"czu{self.index}"

    @property
    def bridge_port(self) -> str:
        """The bridge's port for a rated link (the peer of :attr:`uplink_interface`)."""
        return f"czb{self.index}"

    @property
    def router_endpoint(self) -> str:
        return f"tcp/{self.address}:{ROUTER_PORT}"

    @property
    def listen_endpoint(self) -> str:
        """Where a member on this host listens (any free port on the host's address)."""
        return f"tcp/{self.address}:0"


@dataclass(frozen=True)
class NetPlan:
    prefix: str
    hosts: tuple[NetHost, ...]

    @property
    def hub_namespace(self) -> str:
        return f"{self.prefix}-hub"

    @property
    def namespaces(self) -> tuple[str, ...]:
        """Every namespace of the plan, the hub first."""
        return (self.hub_namespace, *(h.namespace for h in self.hosts))

    def host(self, name: str) -> NetHost:
        for host in self.hosts:
            if host.name == name:
                return host
        raise NetPlanError(f"no host {name!r} in the plan (hosts: {', '.join(h.name for h in self.hosts)})")

    def routers_before(self, name: str) -> tuple[str, ...]:
        """The router endpoints host ``name``'s router connects to: every earlier host's (started first),
        so that the routers form a full mesh without any of them dialling one not yet listening."""
        index = self.host(name).index
        return tuple(h.router_endpoint for h in self.hosts if h.index < index)


def cpu_mask(cpus: str) -> int:
    """The bit mask of a ``taskset`` CPU list (``"1"``, ``"0-3"``, ``"0,2-3"``); a NetPlanError names a list
    that is not one."""
    mask = 0
    for part in cpus.split(","):
        first, _, last = part.strip().partition("-")
        try:
            low, high = int(first), int(last or first)
        except ValueError:
            raise NetPlanError(f"CPU list {cpus!r}: {part!r} is not a CPU or a range") from None
        if not 0 <= low <= high < 1024:
            raise NetPlanError(f"CPU list {cpus!r}: {part!r} is not within 0..1023, low to high")
        for cpu in range(low, high + 1):
            mask |= 1 << cpu
    return mask


def tbf_burst_bytes(rate_bit_s: int) -> int:
    """A token bucket's burst for ``rate_bit_s``: 1 ms of the rate, at least 16 KiB (one full-size segment
    always fits, and the kernel's high-resolution timer keeps the rate at any size from there: 16 KiB moved
    2.6 MB over 1 Gbit in 22.5 ms against the wire's 20.8).

    A bucket starts full after an idle gap, and what it holds crosses at once: a larger burst lets a frame's
    job cross faster than the wire could carry it. The 10 ms of the rate this gave before sent 260 kB over
    100 Mbit in 11.9 ms, not the wire's 20.8 (20.6 ms with 16 KiB; ``tc ... tbf`` on two namespaces, a
    TCP message each half second), which made every distributed path look 9 ms faster a frame."""
    return max(rate_bit_s // 8 // 1000, 16 * 1024)


def make_plan(
    prefix: str,
    names: Sequence[str],
    rates_bit_s: Mapping[str, int | None] | None = None,
    cpus: Mapping[str, str | None] | None = None,
) -> NetPlan:
    """A plan of hosts ``names`` (in order) under ``prefix``; rates and CPU lists by host name."""
    rates = dict(rates_bit_s or {})
    cpu_sets = dict(cpus or {})
    if not PREFIX_PATTERN.match(prefix):
        raise NetPlanError(f"prefix {prefix!r} is not cz<pid>[x<n>]")
    if not names or len(names) > MAX_HOSTS:
        raise NetPlanError(f"a plan needs 1 to {MAX_HOSTS} hosts, not {len(names)}")
    if len(set(names)) != len(names):
        raise NetPlanError(f"host names repeat: {list(names)}")
    if bad := [n for n in names if not HOST_PATTERN.match(n) or n == "hub"]:
        raise NetPlanError(f"host names must be 1-32 of letters, digits, _ . - and not 'hub': {bad}")
    if unknown := sorted(set(rates) - set(names)) + sorted(set(cpu_sets) - set(names)):
        raise NetPlanError(f"rates or CPU sets for hosts not in the plan: {unknown}")
    if slow := {n: r for n, r in rates.items() if r is not None and r < MIN_RATE_BIT_S}:
        raise NetPlanError(f"link rates below {MIN_RATE_BIT_S} bit/s: {slow}")
    hosts = tuple(
        NetHost(
            name=name,
            index=i,
            namespace=f"{prefix}-{name}",
            address=f"{SUBNET}.{i}",
            rate_bit_s=rates.get(name),
            cpus=cpu_sets.get(name),
        )
        for i, name in enumerate(names, start=1)
    )
    return NetPlan(prefix=prefix, hosts=hosts)


def owner_pid(namespace: str) -> int | None:
    """The pid in a harness namespace's name (``cz<pid>[x<n>]-<host>``), None for any other name."""
    prefix, sep, _ = namespace.partition("-")
    match = PREFIX_PATTERN.match(prefix)
    return int(match["pid"]) if sep and match else None
