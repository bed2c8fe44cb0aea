"""Separate network hosts on one machine: a :class:`~common.netplan.NetPlan` carried out with ``ip``/``tc``.

:class:`NetHarness` (a context manager) makes the hub namespace with a bridge, one namespace per host, a veth
link from each host to the bridge (created directly inside the namespaces: the root namespace's interfaces
are never touched), the host's private address on its end, and for a link that has a rate a token bucket
(``tc ... tbf``) for each direction, both in the hub (:meth:`NetHarness._shaped_port`). On exit, an
exception or SIGTERM it kills what still runs inside its namespaces and deletes them (which deletes their
links): nothing it made is left behind. :func:`cleanup_stale` removes the namespaces of harnesses whose
process is gone. :func:`unavailable_reason` says why the harness cannot run here (not root, no ``ip``,
``ip netns`` refused, ``tc`` unable to shape a link in the hub), for tests to skip with.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import json
import logging
import os
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Iterator, Sequence
from types import FrameType
from typing import Any

from common.errors import CapatazError
from common.netplan import BRIDGE, HOST_INTERFACE, NetHost, NetPlan, cpu_mask, owner_pid, tbf_burst_bytes

logger = logging.getLogger(__name__)

_SERIAL = itertools.count()
#: bound of every ``ip``/``tc`` call
COMMAND_TIMEOUT_S = 10.0


class NetnsError(CapatazError):
    """A namespace, link or queue discipline could not be made."""


def new_prefix() -> str:
    """A prefix no other harness uses: this process's pid and a serial number."""
    return f"cz{os.getpid()}x{next(_SERIAL)}"


def _run(argv: Sequence[str]) -> str:
    try:
        done = subprocess.run(list(argv), capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise NetnsError(f"{' '.join(argv)}: {exc}") from None
    if done.returncode != 0:
        raise NetnsError(f"{' '.join(argv)}: {done.stderr.strip() or f'exit {done.returncode}'}")
    return done.stdout


def list_namespaces() -> list[str]:
    """Names in ``ip netns list`` (its lines are ``name`` or ``name (id: n)``)."""
    return [line.split()[0] for line in _run(["ip", "netns", "list"]).splitlines() if line.strip()]


def unavailable_reason() -> str | None:
    """Why the harness cannot run on this machine, or None when it can (root, ``ip`` and ``tc`` present, a
    probe namespace can be made and deleted, and a link shaped in it as the hub shapes one: a token bucket,
    and a redirect from an interface's ingress, :meth:`NetHarness._shaped_port`)."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    for tool in ("ip", "tc"):
        if shutil.which(tool) is None:
            return f"no {tool!r} command"
    probe = f"{new_prefix()}-probe"
    try:
        _run(["ip", "netns", "add", probe])
    except NetnsError as exc:
        return f"ip netns does not work here: {exc}"
    try:
        _run(["ip", "-n", probe, "link", "add", "name", "czq0", "type", "veth", "peer", "name", "czq1"])
        NetHarness._tbf(probe, "czq1", 1_000_000)
        NetHarness._redirect(probe, "czq0", "czq1")
    except NetnsError as exc:
        return f"tc cannot shape a link here (tbf, ingress redirect): {exc}"
    finally:
        with contextlib.suppress(NetnsError):
            _run(["ip", "netns", "del", probe])
    return None


def _pids_in(namespace: str) -> list[int]:
    try:
        return [int(p) for p in _run(["ip", "netns", "pids", namespace]).split()]
    except NetnsError:
        return []


def _remove_namespace(namespace: str, grace_s: float = 2.0) -> None:
    """Stop what runs inside ``namespace`` (SIGTERM, then SIGKILL after ``grace_s``) and delete it."""
    pids = _pids_in(namespace)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + grace_s
        while pids and time.monotonic() < deadline:
            time.sleep(0.05)
            pids = _pids_in(namespace)
        if not pids:
            break
    try:
        _run(["ip", "netns", "del", namespace])
    except NetnsError as exc:
        logger.warning("could not delete namespace %s: %s", namespace, exc)


def cleanup_stale(prefix: str = "cz") -> list[str]:
    """Delete harness namespaces (``cz<pid>...-<host>``) starting with ``prefix`` whose owning process is
    gone; returns their names. A live harness's namespaces and every other namespace are left alone."""
    removed = []
    for namespace in list_namespaces():
        pid = owner_pid(namespace)
        if pid is None or not namespace.startswith(prefix) or _alive(pid):
            continue
        _remove_namespace(namespace)
        removed.append(namespace)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def link_bytes_per_frame(
    before: dict[str, tuple[int, int]], after: dict[str, tuple[int, int]], frames: int
) -> dict[str, dict[str, float]]:
    """Each host's link: bytes received and sent per frame between two readings of
    :meth:`NetHarness.link_bytes` (``frames`` at least 1)."""
    n = max(frames, 1)
    return {
        host: {
            "rx_bytes_per_frame": (after[host][0] - rx0) / n,
            "tx_bytes_per_frame": (after[host][1] - tx0) / n,
        }
        for host, (rx0, tx0) in before.items()
    }


#: ``setns``'s flag for a network namespace (linux/sched.h)
_CLONE_NEWNET = 0x40000000


def _setns_fd(fd: int) -> None:
    if ctypes.CDLL(None, use_errno=True).setns(fd, _CLONE_NEWNET) != 0:
        raise NetnsError(f"setns: {os.strerror(ctypes.get_errno())}")


def _setns(path: str) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError as exc:
        raise NetnsError(f"cannot open {path}: {exc}") from None
    try:
        _setns_fd(fd)
    finally:
        os.close(fd)


class NetHarness:
    """The plan's namespaces and links, made on enter and always removed on exit (also on SIGTERM)."""

    def __init__(self, plan: NetPlan) -> None:
        self.plan = plan
        #: namespaces made so far (removed on exit, in reverse)
        self.made: list[str] = []
        self._previous_sigterm: Any = None
        self._closed = False

    # -- commands inside a host ---------------------------------------------------------------------------
    def exec_argv(self, host: str, argv: Sequence[str], cpus: str | None = None) -> list[str]:
        """``argv`` run inside ``host``'s namespace, pinned to ``cpus`` (default: the host's CPU set)."""
        net_host = self.plan.host(host)
        pinned = cpus if cpus is not None else net_host.cpus
        taskset = ["taskset", "-c", pinned] if pinned and shutil.which("taskset") else []
        return ["ip", "netns", "exec", net_host.namespace, *taskset, *argv]

    @contextlib.contextmanager
    def joined(self, host: str) -> Iterator[None]:
        """The calling thread inside ``host``'s namespace for the block (``setns``), then back where it was:
        sessions and threads it opens meanwhile live in that host (a harness that publishes and watches from
        the ground host). Join before the process opens its first Zenoh session: Zenoh's own threads stay in
        the namespace they were started in. Leave it before the harness closes: closing stops what runs in
        its namespaces."""
        here = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
        try:
            _setns(f"/run/netns/{self.plan.host(host).namespace}")
            try:
                yield
            finally:
                _setns_fd(here)
        finally:
            os.close(here)

    def link_bytes(self) -> dict[str, tuple[int, int]]:
        """Bytes each host received and sent on its link since it was made (the veth's counters)."""
        counts = {}
        for host in self.plan.hosts:
            out = _run(["ip", "-n", host.namespace, "-s", "-j", "link", "show", HOST_INTERFACE])
            try:
                stats = json.loads(out)[0]["stats64"]
                counts[host.name] = (int(stats["rx"]["bytes"]), int(stats["tx"]["bytes"]))
            except (ValueError, LookupError, TypeError) as exc:
                raise NetnsError(f"no counters of {host.namespace}/{HOST_INTERFACE}: {exc}") from None
        return counts

    # -- making and removing -------------------------------------------------------------------------------
    def _netns(self, namespace: str) -> None:
        _run(["ip", "netns", "add", namespace])
        self.made.append(namespace)

    def _in(self, namespace: str, *argv: str) -> None:
        _run(["ip", "-n", namespace, *argv])

    @staticmethod
    def _tbf(namespace: str, interface: str, rate_bit_s: int) -> None:
        burst = tbf_burst_bytes(rate_bit_s)
        _run(["tc", "-n", namespace, "qdisc", "add", "dev", interface, "root", "tbf",
              "rate", f"{rate_bit_s}bit", "burst", str(burst), "latency", "100ms"])  # fmt: skip

    def _link(self, host: NetHost) -> None:
        hub = self.plan.hub_namespace
        self._netns(host.namespace)
        # both ends are born inside their namespaces: nothing appears in the root namespace
        _run(["ip", "link", "add", HOST_INTERFACE, "netns", host.namespace, "type", "veth", "peer", "name",
              host.hub_interface, "netns", hub])  # fmt: skip
        self._in(host.namespace, "link", "set", "lo", "up")
        self._in(host.namespace, "addr", "add", f"{host.address}/24", "dev", HOST_INTERFACE)
        self._in(host.namespace, "link", "set", HOST_INTERFACE, "up")
        if host.rate_bit_s is None:
            self._in(hub, "link", "set", host.hub_interface, "master", BRIDGE)
        else:
            self._shaped_port(host, host.rate_bit_s)
        self._in(hub, "link", "set", host.hub_interface, "up")
        if host.cpus:  # what arrives on a pinned host's link is processed on its CPUs
            self._steer_receive(host.namespace, HOST_INTERFACE, cpu_mask(host.cpus))

    def _shaped_port(self, host: NetHost, rate_bit_s: int) -> None:
        """A rated link's two token buckets, both in the hub: what the host sends is redirected from its
        link's hub end to the uplink's bucket (:attr:`~common.netplan.NetHost.uplink_interface`), whose peer
        joins the bridge; what the bridge sends it comes back the same way to the downlink's bucket, on the
        link's hub end.

        A bucket on the host's own end (the harness before) ran on the host's CPU: the kernel cut each 64 kB
        segment to the bucket's size there and woke a timer for every release, about 100 timer interrupts
        and as many cross-CPU hand-overs for a 1080p frame's job, in the middle of the master's own share.
        A NIC shapes its wire in its own silicon; here the hub's CPUs (:meth:`_steer_links`) do it."""
        hub = self.plan.hub_namespace
        _run(["ip", "link", "add", host.uplink_interface, "netns", hub, "type", "veth", "peer", "name",
              host.bridge_port, "netns", hub])  # fmt: skip
        self._in(hub, "link", "set", host.bridge_port, "master", BRIDGE)
        for interface in (host.uplink_interface, host.bridge_port):
            self._in(hub, "link", "set", interface, "up")
        self._redirect(hub, host.hub_interface, host.uplink_interface)  # host -> hub
        self._redirect(hub, host.uplink_interface, host.hub_interface)  # hub -> host
        self._tbf(hub, host.uplink_interface, rate_bit_s)
        self._tbf(hub, host.hub_interface, rate_bit_s)

    @staticmethod
    def _redirect(namespace: str, source: str, target: str) -> None:
        """Everything arriving on ``source`` leaves by ``target`` (through ``target``'s queue discipline)."""
        _run(["tc", "-n", namespace, "qdisc", "add", "dev", source, "ingress"])
        _run(["tc", "-n", namespace, "filter", "add", "dev", source, "parent", "ffff:", "protocol", "all",
              "u32", "match", "u32", "0", "0",  # every packet
              "action", "mirred", "egress", "redirect", "dev", target])  # fmt: skip

    def _steer_links(self) -> None:
        """Where the kernel processes each link's packets (receive packet steering): a pinned host's on its
        own CPUs (:meth:`_link`), and what a host sends into the hub (the bridge, the token buckets, the
        hand-over to the receiver) on the other pinned hosts' CPUs. Inside the hub a packet stays on the CPU
        it entered on (the shaped ports' pairs are not steered).

        A veth hands a packet to its peer on the sending CPU, so without it everything a 500 kB job crossing
        the link costs the kernel (the bridge, two token buckets, hundreds of segments, the receiver's TCP)
        ran on the ground host's CPU, in the master's time, while it computed its own share; on separate
        machines the switch and the receiver do that work."""
        for host in self.plan.hosts:
            others = [h.cpus for h in self.plan.hosts if h.cpus and h is not host]
            mask = 0
            for cpus in others:
                mask |= cpu_mask(cpus)
            if mask:
                self._steer_receive(self.plan.hub_namespace, host.hub_interface, mask)

    def _steer_receive(self, namespace: str, interface: str, mask: int) -> None:
        path = f"/sys/class/net/{interface}/queues/rx-0/rps_cpus"
        _run(["ip", "netns", "exec", namespace, "sh", "-c", f"echo {mask:x} > {path}"])

    def open(self) -> None:
        hub = self.plan.hub_namespace
        self._netns(hub)
        self._in(hub, "link", "add", BRIDGE, "type", "bridge")
        self._in(hub, "link", "set", BRIDGE, "up")
        for host in self.plan.hosts:
            self._link(host)
        self._steer_links()
        logger.info(
            "network hosts up: %s",
            ", ".join(f"{h.name}={h.address}" + (f"@{h.rate_bit_s}bit/s" if h.rate_bit_s else "")
                      for h in self.plan.hosts),
        )  # fmt: skip

    def close(self) -> None:
        """Remove every namespace this harness made (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for namespace in reversed(self.made):
            _remove_namespace(namespace)
        self.made.clear()

    def _on_sigterm(self, signum: int, frame: FrameType | None) -> None:
        raise SystemExit(128 + signum)  # unwinds the with-block: __exit__ removes everything

    def __enter__(self) -> NetHarness:
        if stale := cleanup_stale():  # a harness that was SIGKILLed left these (their owner is gone)
            logger.warning("removed namespaces of harnesses that are gone: %s", ", ".join(stale))
        if threading.current_thread() is threading.main_thread():
            self._previous_sigterm = signal.signal(signal.SIGTERM, self._on_sigterm)
        try:
            self.open()
        except BaseException:
            self.close()
            self._restore()
            raise
        return self

    def _restore(self) -> None:
        if self._previous_sigterm is not None:
            signal.signal(signal.SIGTERM, self._previous_sigterm)
            self._previous_sigterm = None

    def __exit__(self, *_exc: Any) -> None:
        try:
            self.close()
        finally:
            self._restore()


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "netns", help="emulated network hosts: check the machine, remove leftovers"
    )
    sub = parser.add_subparsers(dest="netns_command", required=True, metavar="WHAT")
    sub.add_parser("check", help="say whether network namespaces can be made here (root, ip, tc)")
    cleanup = sub.add_parser("cleanup", help="delete namespaces of harnesses whose process is gone")
    cleanup.add_argument("--prefix", default="cz", help="only namespaces starting with this (default cz)")
    parser.set_defaults(handler=run)


def run(args: Any) -> int:
    if (reason := unavailable_reason()) is not None:
        print(f"network namespaces unavailable: {reason}")
        return 1
    if args.netns_command == "check":
        print("network namespaces available")
        return 0
    removed = cleanup_stale(args.prefix)
    print(f"removed {len(removed)} namespace(s){': ' + ', '.join(removed) if removed else ''}")
    return 0
