"""A cluster file's hosts as separate network hosts: :class:`NetnsCluster` runs a :class:`LocalCluster` inside
the namespaces of a :class:`~services.tools.netns.NetHarness`.

Each host of the plan gets its own Zenoh router on its private address (port 7447), connected to every
earlier host's router (a full mesh; explicit endpoints, multicast off, shared memory off: a payload must cross
the emulated link). Workers and the foreman of a cluster host run in that host's namespace; the master and
the camera in the ``ground`` host (:func:`plan_for_cluster`). Every member listens on its host's address, so
the peers that Zenoh's gossip connects directly reach each other over the links (and their rates) too.
Watching is done from inside a host by :mod:`services.tools.netns_agent` (:meth:`NetnsCluster.agent`).
"""

from __future__ import annotations

import json
import logging
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from common.netplan import NetPlan, make_plan
from services.tools.cluster_file import ClusterError, ClusterSpec
from services.tools.netns import NetHarness
from services.tools.up import LocalCluster

logger = logging.getLogger(__name__)

#: the host of the master, the camera and the watchers
GROUND = "ground"


def plan_for_cluster(
    spec: ClusterSpec, prefix: str, rates_bit_s: Mapping[str, int | None] | None = None, ground: str = GROUND
) -> NetPlan:
    """The ground host (master, camera) then one host per cluster host, with the cluster's CPU sets."""
    names = [ground, *(h.name for h in spec.hosts)]
    return make_plan(prefix, names, rates_bit_s, {h.name: h.cpus for h in spec.hosts})


class Agent:
    """A :mod:`services.tools.netns_agent` process inside a host: ``ready`` then one JSON line."""

    def __init__(self, argv: list[str], log_path: Path) -> None:
        self.argv = argv
        #: its stderr (a file: a pipe nobody reads could fill and block it)
        self.log_path = log_path
        log_path.parent.mkdir(parents=True, exist_ok=True)
        with log_path.open("ab") as log:
            self.process: subprocess.Popen[str] = subprocess.Popen(
                argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, text=True
            )
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line.strip())
        self._lines.put(None)

    def _next(self, timeout_s: float) -> str | None:
        try:
            return self._lines.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def wait_ready(self, timeout_s: float = 30.0) -> None:
        if self._next(timeout_s) != "ready":
            raise ClusterError(f"agent {self.argv} not ready: {self._stderr()}")

    def result(self, timeout_s: float) -> dict[str, Any]:
        """The agent's JSON line (bounded wait); ClusterError when it ended without one."""
        if self.process.stdin is not None and not self.process.stdin.closed:
            self.process.stdin.close()  # a ``serve`` agent ends when its stdin closes
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            line = self._next(left)
            if line is None:
                break
            if line.startswith("{"):
                self.process.wait(max(1.0, deadline - time.monotonic()))
                return dict(json.loads(line))
        self.close()
        raise ClusterError(f"agent {self.argv} gave no result: {self._stderr()}")

    def _stderr(self) -> str:
        try:
            tail = self.log_path.read_text(errors="replace")[-500:].strip()
        except OSError:
            tail = ""
        state = "running" if self.process.poll() is None else f"exit {self.process.returncode}"
        return f"{state}; {tail or 'no output'} ({self.log_path})"

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(3.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


class NetnsCluster(LocalCluster):
    """A :class:`LocalCluster` whose processes run in the hosts of ``net`` (an open harness)."""

    def __init__(
        self, spec: ClusterSpec, log_dir: Path, net: NetHarness, ground: str = GROUND, **kwargs: Any
    ) -> None:
        super().__init__(spec, log_dir, shared_memory=False, **kwargs)
        self.net = net
        self.ground = ground
        self.agents: list[Agent] = []

    def host_of(self, name: str) -> str:
        """The host a process runs on: routers, workers and foremen on the node they name, the rest on
        the ground host."""
        role, _, rest = name.partition("/")
        node = rest.split("/", 1)[0]
        return node if role in ("router", "worker", "foreman") else self.ground

    @property
    def router(self) -> str:
        return self.net.plan.host(self.ground).router_endpoint

    def transport_args(self, name: str | None = None) -> list[str]:
        host = self.net.plan.host(self.host_of(name or self.ground))
        return ["--connect", host.router_endpoint, "--listen", host.listen_endpoint, "--no-multicast",
                "--no-shm", "--lease-ms", str(self.lease_ms)]  # fmt: skip

    def launch_argv(self, name: str, command: list[str], cpus: str | None) -> list[str]:
        return self.net.exec_argv(self.host_of(name), command, cpus)

    def start_router(self, timeout_s: float = 30.0) -> None:
        """One router per host, in plan order, each connected to the routers already up; a member host's
        router runs on that host's CPU set (the ground's with the camera, on the cluster's aux CPUs)."""
        cpus_of = {h.name: h.cpus for h in self.spec.hosts if h.name != self.ground}
        for host in self.net.plan.hosts:
            name = f"router/{host.name}/0"
            endpoint_file = self.log_dir / f"router_{host.name}.endpoint"
            endpoint_file.unlink(missing_ok=True)
            connect = [a for e in self.net.plan.routers_before(host.name) for a in ("--connect", e)]
            self.spawn(
                name,
                ["router", "--node", host.name, "--listen", host.router_endpoint, *connect, "--no-multicast",
                 "--no-shm", "--lease-ms", str(self.lease_ms), "--endpoint-file", str(endpoint_file)],
                cpus_of.get(host.name, self.spec.aux_cpus),
            )  # fmt: skip
            deadline = time.monotonic() + timeout_s
            while not endpoint_file.is_file():
                if self.processes[name].poll() is not None or time.monotonic() > deadline:
                    raise ClusterError(f"{name} did not start listening; see {self.log_dir}")
                time.sleep(0.05)
        self.port = 7447

    def agent(self, host: str, mode: Sequence[str], timeout_s: float = 30.0) -> Agent:
        """Start a :mod:`services.tools.netns_agent` in ``host`` (connected to that host's router)."""
        net_host = self.net.plan.host(host)
        argv = [sys.executable, "-m", "services.tools.netns_agent", "--connect", net_host.router_endpoint,
                "--listen", net_host.listen_endpoint, "--timeout", str(timeout_s), *mode]  # fmt: skip
        log_path = self.log_dir / f"agent_{host}_{len(self.agents)}_{mode[0]}.log"
        agent = Agent(self.net.exec_argv(host, argv), log_path)
        self.agents.append(agent)
        return agent

    def wait_alive(self, names: set[str], timeout_s: float = 60.0) -> dict[str, float]:
        """Wait (from the ground host) until every name has a liveliness token; start-up times are not
        measured here (an empty mapping)."""
        result = self.agent(self.ground, ["alive", *sorted(names)], timeout_s).result(timeout_s + 15.0)
        if result["missing"]:
            dead = sorted(n for n, p in self.processes.items() if p.poll() is not None)
            raise ClusterError(f"not alive after {timeout_s:.0f} s: {result['missing']} (exited: {dead}); "
                               f"see logs in {self.log_dir}")  # fmt: skip
        return {}

    def stop(self, grace_s: float = 3.0) -> dict[str, int | None]:
        for agent in self.agents:
            agent.close()
        return super().stop(grace_s)
