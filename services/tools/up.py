"""``capataz up --cluster deploy/clusters/2h8n.yml``: start a described cluster locally as processes.

The cluster file (its format: :mod:`services.tools.cluster_file`) describes the hosts. :class:`LocalCluster`
starts the router, the workers, the foremen and the master (and a camera when asked) on 127.0.0.1 with
explicit endpoints and multicast scouting off, and stops them with SIGTERM (SIGKILL after a grace period).
Tests, the demo and the benchmark use it too."""

from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Self

from services.runtime.allocator import process_environment
from services.runtime.transport import TransportSettings, open_session
from services.tools.cluster_file import (
    ClusterError,
    ClusterSpec,
    HostSpec,
    ServiceCommand,
    cluster_commands,
    foreman_command,
    master_command,
    worker_command,
)
from services.tools.observe import AliveWatch
from services.tools.secure import SecureProfile, participant_environment, process_common_name

logger = logging.getLogger(__name__)


def check_port_free(port: int, host: str = "127.0.0.1") -> None:
    """ClusterError when something already listens on ``host:port`` (a router of another cluster)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # TIME_WAIT leftovers do not count
        try:
            sock.bind((host, port))
        except OSError as exc:
            raise ClusterError(
                f"the router cannot listen on tcp/{host}:{port}: {exc.strerror} (another router? "
                f"choose --port, or --port 0 for any free port)"
            ) from None


def capataz_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "services.tools.cli", *args]


class LocalCluster:
    """Processes of one cluster on 127.0.0.1; a context manager that always stops what it started."""

    def __init__(
        self,
        spec: ClusterSpec,
        log_dir: Path,
        port: int | None = None,
        shared_memory: bool = False,
        master_args: Sequence[str] = (),
        lease_ms: int = 2000,
        secure: SecureProfile | None = None,
        zenoh_config: Path | None = None,
    ) -> None:
        self.spec = spec
        self.log_dir = Path(log_dir)
        #: the router's port; None = any free port, chosen by the router itself (no reservation race)
        self.port = port or None
        #: the secure profile: mutual TLS with per-role certificates and access control on every participant
        self.secure = secure
        self.scheme = "tls" if secure is not None else "tcp"
        #: a zenoh configuration file every process (and our own sessions) loads (the secure one wins)
        self.zenoh_config = Path(zenoh_config).resolve() if zenoh_config else None
        self.shared_memory = shared_memory
        self.master_args = tuple(master_args)
        self.lease_ms = lease_ms
        self.processes: dict[str, subprocess.Popen[bytes]] = {}
        #: ``time.monotonic()`` when each process was started (start-up times in ``capataz up``'s summary)
        self.spawned_at: dict[str, float] = {}
        #: how each process was started (``spawn``'s arguments), for :meth:`respawn`
        self._spawned: dict[str, tuple[tuple[str, ...], str | None, str | None]] = {}
        self._stopped: set[str] = set()
        self._taskset = shutil.which("taskset")

    @property
    def router(self) -> str:
        """The router's endpoint (known once :meth:`start_router` returned)."""
        if self.port is None:
            raise ClusterError("the router's endpoint is known only after start_router()")
        return f"{self.scheme}/127.0.0.1:{self.port}"

    # -- processes --------------------------------------------------------------------------------------
    def transport_args(self, name: str | None = None) -> list[str]:
        """Transport options of member ``name`` (here the same for every member)."""
        return [
            "--connect",
            self.router,
            "--listen",
            f"{self.scheme}/127.0.0.1:0",
            "--no-multicast",
            "--shm" if self.shared_memory else "--no-shm",
            "--lease-ms",
            str(self.lease_ms),
        ]

    def observer_transport(self) -> TransportSettings:
        """The transport of our own observing session (a read-only ``client`` in the secure profile)."""
        return self.participant_transport("client")

    def participant_transport(self, common_name: str) -> TransportSettings:
        """The transport of a session of our own holding ``common_name``'s certificate (secure profile),
        e.g. ``camera.uav3`` for a harness that publishes that UAV's frames."""
        return TransportSettings.from_env(
            environ=participant_environment(self.secure, self.zenoh_config, common_name),
            connect=(self.router,),
            listen=(f"{self.scheme}/127.0.0.1:0",),
            shared_memory=self.shared_memory,
            lease_ms=self.lease_ms,
        )

    def spawn(
        self, name: str, args: Sequence[str], cpus: str | None = None, common_name: str | None = None
    ) -> subprocess.Popen[bytes]:
        if name in self.processes and self.processes[name].poll() is None:
            raise ClusterError(f"{name} is already running")
        command = self.launch_argv(name, capataz_command(*args), cpus)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = (self.log_dir / f"{name.replace('/', '_')}.log").open("ab")
        cn = common_name or process_common_name(name, self.spec.uav)
        env = dict(
            os.environ, PYTHONUNBUFFERED="1", **participant_environment(self.secure, self.zenoh_config, cn)
        )
        env.update(process_environment(env))  # the compute services' heap policy (one malloc arena)
        process = subprocess.Popen(
            command, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
        log.close()
        self.processes[name] = process
        self.spawned_at[name] = time.monotonic()
        self._spawned[name] = (tuple(args), cpus, common_name)
        self._stopped.discard(name)
        return process

    def respawn(self, name: str) -> subprocess.Popen[bytes]:
        """Start process ``name`` again as it was started (it must have exited)."""
        args, cpus, common_name = self._spawned[name]
        return self.spawn(name, args, cpus, common_name)

    def launch_argv(self, name: str, command: list[str], cpus: str | None) -> list[str]:
        """How process ``name`` is started: here pinned to ``cpus`` with taskset (when given and present)."""
        if cpus is not None and self._taskset:
            return [self._taskset, "-c", cpus, *command]
        return command

    def start_router(self, timeout_s: float = 30.0) -> None:
        """Start the router and wait until it listens; with no port given it picks a free one itself and
        reports it through an endpoint file (reserving a port first races with every other process)."""
        if self.port is not None:
            check_port_free(self.port)  # else the members would join whichever router holds the port
        endpoint_file = self.log_dir / "router.endpoint"
        endpoint_file.unlink(missing_ok=True)
        listen = f"{self.scheme}/127.0.0.1:{self.port or 0}"
        self.spawn(
            "router",
            ["router", "--listen", listen, "--no-multicast", "--no-shm", "--lease-ms", str(self.lease_ms),
             "--endpoint-file", str(endpoint_file)],
            self.spec.aux_cpus,
        )  # fmt: skip
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if endpoint_file.is_file():  # written (atomically) once the router's session listens
                self.port = self._router_port(endpoint_file.read_text().split())
                return
            if self.processes["router"].poll() is not None:
                raise ClusterError(
                    f"router exited with {self.processes['router'].returncode}; see {self.log_dir}"
                )
            time.sleep(0.05)
        raise ClusterError(f"router did not start listening within {timeout_s:.0f} s")

    def _router_port(self, endpoints: list[str]) -> int:
        prefix = f"{self.scheme}/"
        for endpoint in endpoints:
            host, _, port = endpoint.removeprefix(prefix).rpartition(":")
            if endpoint.startswith(prefix) and host == "127.0.0.1" and port.isdigit():
                return int(port)
        raise ClusterError(f"the router listens on no {prefix}127.0.0.1 endpoint: {endpoints}")

    def start_command(self, command: ServiceCommand, extra: Sequence[str] = ()) -> str:
        self.spawn(command.name, [*command.args, *extra, *self.transport_args(command.name)], command.cpus)
        return command.name

    def start_worker(self, host: HostSpec, index: int) -> str:
        return self.start_command(worker_command(self.spec, host, index))

    def start_foreman(self, host: HostSpec, extra: Sequence[str] = ()) -> str:
        return self.start_command(foreman_command(self.spec, host), extra)

    def start_master(self, extra: Sequence[str] = ()) -> str:
        return self.start_command(master_command(self.spec), [*self.master_args, *extra])

    def start_camera(self, extra: Sequence[str] = ()) -> str:
        name = "camera/camera/0"
        self.spawn(
            name, ["camera", *self.transport_args(name), "--uav", self.spec.uav, *extra], self.spec.aux_cpus
        )
        return name

    def expected_members(self) -> set[str]:
        return {command.name for command in cluster_commands(self.spec)}

    def start(self, with_master: bool = True) -> None:
        """Router, then workers, foremen (for that topology) and the master, all in parallel."""
        self.start_router()
        for command in cluster_commands(self.spec):
            if command.name != "master/master/0":
                self.start_command(command)
        if with_master:
            self.start_master()

    def wait_alive(self, names: set[str], timeout_s: float = 60.0) -> dict[str, float]:
        """Wait until every name has a liveliness token (observed from a session of our own); returns the
        seconds each member took from its start to its token (as first seen here)."""
        t0 = time.monotonic()

        def give_up_on_exits() -> None:
            # a process awaited, or any that failed (a camera whose flight ended is not a failure)
            dead = [
                n
                for n, p in self.processes.items()
                if p.poll() is not None and n not in self._stopped and (n in names or p.returncode)
            ]
            if dead:
                raise ClusterError(f"{dead} exited during start-up; see logs in {self.log_dir}")

        with open_session(self.observer_transport()) as session:
            watch = AliveWatch(session)
            try:
                if not watch.wait_for(names, timeout_s, give_up_on_exits):
                    missing = sorted(names - watch.names())
                    raise ClusterError(f"not alive after {timeout_s:.0f} s: {missing}")
            finally:
                watch.close()
        return {n: t - self.spawned_at.get(n, t0) for n, t in watch.first_seen_s.items()}

    def signal(self, name: str, sig: int) -> None:
        process = self.processes[name]
        if process.poll() is None:
            os.kill(process.pid, sig)
        if sig in (signal.SIGKILL, signal.SIGTERM):
            self._stopped.add(name)

    def stop(self, grace_s: float = 3.0) -> dict[str, int | None]:
        """SIGCONT + SIGTERM everything, SIGKILL what is still running after ``grace_s``; exit codes."""
        order = sorted(self.processes, key=lambda n: n.startswith("router"))  # router last
        for name in order:
            process = self.processes[name]
            if process.poll() is None:
                try:
                    os.kill(process.pid, signal.SIGCONT)
                    os.kill(process.pid, signal.SIGTERM)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace_s
        codes: dict[str, int | None] = {}
        for name in order:
            process = self.processes[name]
            try:
                process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                logger.warning("%s did not stop within %.1f s: SIGKILL", name, grace_s)
                process.kill()
                process.wait()
            codes[name] = process.returncode
        return codes

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: Any) -> None:
        self.stop()


def register(subparsers: Any) -> None:
    """The ``up`` command lives in :mod:`services.tools.up_command`; this module holds the cluster itself."""
    from services.tools.up_command import register as register_command

    register_command(subparsers)
