"""The I/O of ``capataz loadtest``: a local cluster, N simulated UAV camera streams at their real rate with
wall-clock stamps, and the fault schedule applied (what is observed of a run: :mod:`.observers`).

Frames are paper A's hover, rendered once (ping-pong over ``loop_frames`` frames, so the motion stays
continuous) and shared by the streams at different phases; the publisher costs a few hundred microseconds
per frame, so the cluster, not the harness, is what is measured.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common.wire import keys
from common.wire.codec import encode
from common.wire.messages import Frame, PatchJob, YawJobSettings
from common.yaw import YawSettings, for_frame
from services.runtime.transport import open_session
from services.tools.cluster_file import ClusterSpec, master_command
from services.tools.loadtest.plan import Fault, FaultAction
from services.tools.netns import NetHarness
from services.tools.netns_cluster import NetnsCluster
from services.tools.secure import SecureProfile
from services.tools.up import LocalCluster

logger = logging.getLogger(__name__)


#: the name of this process (it publishes the cameras' frames) among the processes' CPU seconds
HARNESS = "harness"


@dataclass
class RunSettings:
    streams: int = 4
    fps: float = 20.0
    duration_s: float = 30.0
    #: frames a stream may have without a yaw before it waits (0 = free-running camera)
    in_flight: int = 0
    standby_masters: bool = False
    shared_memory: bool = False
    loop_frames: int = 120
    seed: int = 0
    faults: tuple[Fault, ...] = ()
    lease_ms: int = 2000
    #: seconds every stream sends before the clock starts (not measured; reported apart); the streams
    #: join one after another over its first half, like a ramp
    warmup_s: float = 4.0
    #: replay this recording's frames instead of the simulated hover (``capataz record``)
    replay: Path | None = None
    replay_uav: str | None = None
    #: the secure profile's folder (``capataz loadtest --secure``): mutual TLS + access control; None = open
    secure_dir: Path | None = None
    #: a zenoh configuration file every process and the harness's sessions load (``--zenoh-config``)
    zenoh_config: Path | None = None

    @property
    def warmup_frames(self) -> int:
        return round(self.warmup_s * self.fps)

    def first_frame(self, stream: int) -> int:
        """The warm-up frame stream ``stream`` starts with (the ramp: stream 0 at once, the last one half-way
        through the warm-up)."""
        return (stream * self.warmup_frames) // (2 * self.streams)


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a process (Linux /proc), None when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def processes_cpu_seconds(processes: Mapping[str, subprocess.Popen[bytes]]) -> dict[str, float]:
    """:func:`cpu_seconds` of every named process that has a reading; one that ended but was not reaped yet
    (a camera after its flight, when nothing polls it) still has its totals in /proc."""
    readings = {name: cpu_seconds(process.pid) for name, process in processes.items()}
    return {name: value for name, value in readings.items() if value is not None}


class LoadCluster:
    """A :class:`LocalCluster` with one master per UAV (plus a standby each, when asked); with ``net``, a
    :class:`~services.tools.netns_cluster.NetnsCluster` whose hosts are the harness's emulated hosts (the
    masters on the ground host, where the caller's sessions must be: :meth:`NetHarness.joined`)."""

    def __init__(
        self, spec: ClusterSpec, settings: RunSettings, log_dir: Path, net: NetHarness | None = None
    ) -> None:
        self.settings = settings
        self.uavs = [f"uav{i}" for i in range(settings.streams)]
        nodes = tuple(h.name for h in spec.hosts)
        secure = (
            SecureProfile.ensure(settings.secure_dir, tuple(self.uavs), nodes)
            if settings.secure_dir
            else None
        )
        self.net = net
        self.cluster: LocalCluster = (
            NetnsCluster(spec, log_dir, net, lease_ms=settings.lease_ms, zenoh_config=settings.zenoh_config)
            if net is not None
            else LocalCluster(
                spec, log_dir, shared_memory=settings.shared_memory, lease_ms=settings.lease_ms,
                secure=secure, zenoh_config=settings.zenoh_config,
            )
        )  # fmt: skip
        self._master_args: dict[str, list[str]] = {}
        self._master_uav: dict[str, str] = {}
        self.cpu: dict[str, float] = {}
        self._cpu0: dict[str, float] = {}
        #: each emulated host's link counters (received, sent) at the measured window's start and end
        self.links_before: dict[str, tuple[int, int]] = {}
        self.links_after: dict[str, tuple[int, int]] = {}

    def start(self) -> None:
        cluster, spec = self.cluster, self.cluster.spec
        cluster.start(with_master=False)
        for i, uav in enumerate(self.uavs):
            for role in ("m", "s") if self.settings.standby_masters else ("m",):
                node = f"{role}{i}"
                command = master_command(spec, node, uav)
                name, args = command.name, [command.args[0], *cluster.transport_args(), *command.args[1:]]
                self._master_args[name] = args
                self._master_uav[name] = uav
                cluster.spawn(name, args, spec.master_cpus, common_name=f"master.{uav}")
        members = cluster.expected_members() - {"master/master/0"} | set(self._master_args)
        cluster.wait_alive(members, timeout_s=120.0)

    def camera_sessions(self, stack: ExitStack, observer: zenoh.Session) -> dict[str, zenoh.Session]:
        """The session that publishes each UAV's frames: the observer's own in the open profile; in the
        secure profile one per UAV holding that UAV's camera certificate (only it may put the frames)."""
        if self.cluster.secure is None:
            return dict.fromkeys(self.uavs, observer)
        return {
            uav: stack.enter_context(open_session(self.cluster.participant_transport(f"camera.{uav}")))
            for uav in self.uavs
        }

    def wait_leaders(self, session: zenoh.Session, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if all(self.leader(session, uav) for uav in self.uavs):
                return
            time.sleep(0.2)
        raise TimeoutError("not every UAV has an active master")

    @staticmethod
    def leader(session: zenoh.Session, uav: str) -> str | None:
        for reply in session.liveliness().get(keys.election_all(uav), timeout=2.0):
            key = str(reply.ok.key_expr) if reply.ok is not None else ""
            if "/leader/" in key:
                node, index = key.split("/leader/", 1)[1].split("/")
                return f"master/{node}/{index}"
        return None

    def mark_cpu(self) -> None:
        """Start of the measured window: each process's CPU, this process's (it publishes the cameras'
        frames) and, across hosts, each link's bytes."""
        self._cpu0.update(processes_cpu_seconds(self.cluster.processes))
        self._cpu0[HARNESS] = time.process_time()
        self.links_before = self.net.link_bytes() if self.net is not None else {}

    def collect_cpu(self) -> None:
        for name, value in processes_cpu_seconds(self.cluster.processes).items():
            self.cpu[name] = round(value - self._cpu0.get(name, 0.0), 3)
        self.cpu[HARNESS] = round(time.process_time() - self._cpu0[HARNESS], 3)
        if self.net is not None:
            self.links_after = self.net.link_bytes()

    def restart(self, name: str) -> None:
        """Start ``name`` again, as a supervisor (compose's restart policy) would."""
        cluster, spec = self.cluster, self.cluster.spec
        if name == "router":
            cluster.start_router()
            return
        role, node, index = name.split("/")
        if role == "master":
            uav = self._master_uav[name]
            cluster.spawn(name, self._master_args[name], spec.master_cpus, common_name=f"master.{uav}")
        elif role == "foreman":
            cluster.start_foreman(next(h for h in spec.hosts if h.name == node))
        elif role == "worker":
            cluster.start_worker(next(h for h in spec.hosts if h.name == node), int(index))

    def stop(self) -> dict[str, int | None]:
        return self.cluster.stop()


def apply_fault(
    load: LoadCluster, session: zenoh.Session, fault: Fault, hostile: Callable[[str], None]
) -> str:
    """Carry out one fault now (a stop resumes itself after its duration); returns what was hit."""
    if fault.action is FaultAction.HOSTILE:
        hostile(fault.target)
        return f"hostile {fault.target}"
    spec = load.cluster.spec
    if fault.target == "master":
        name = load.leader(session, load.uavs[0]) or "master/m0/0"
    elif fault.target == "router":
        name = "router"
    elif fault.target == "foreman":
        name = f"foreman/{spec.hosts[-1].name}/0"
    else:
        name = f"worker/{spec.hosts[0].name}/0"
    if fault.action is FaultAction.KILL:
        load.cluster.signal(name, signal.SIGKILL)
        load.cluster.processes[name].wait(5.0)
        load.restart(name)
    else:
        load.cluster.signal(name, signal.SIGSTOP)
        timer = threading.Timer(fault.duration_s, load.cluster.signal, (name, signal.SIGCONT))
        timer.daemon = True
        timer.start()
    return name


class Hostile:
    """Hostile but valid messages on the first stream's keys and to a worker (``hostile:KIND@Ts``).

    Frames declare the camera's own sender (a forger that copies its id), so that the master's stream gate,
    not its sender check, has to refuse them; ``sender`` frames come from a second publisher instead, with
    the seq the camera sends next and a current stamp (they continue the stream but for their sender)."""

    def __init__(
        self,
        session: zenoh.Session,
        camera: Any,
        spec: ClusterSpec,
        uav: str,
        shape: tuple[int, int],
        next_seq: Callable[[], int],
    ) -> None:
        self.session, self.camera, self.spec, self.uav = session, camera, spec, uav
        self.height, self.width = shape
        #: the seq the stream's camera sends next (a second sender forges it)
        self.next_seq = next_seq
        self.sent: dict[str, int] = {}

    def __call__(self, kind: str) -> None:
        rng = np.random.default_rng(len(self.sent))
        now = time.time()
        h, w = self.height, self.width
        pixels = rng.integers(0, 255, (h, w), dtype=np.uint8)
        frames: list[Frame] = []
        if kind == "seq":
            frames.append(Frame(uav=self.uav, seq=2**53, stamp_s=now, width=w, height=h, pixels=pixels))
        elif kind == "restart":  # two frames of a "restarted camera" (a third would confirm a new epoch)
            frames += [
                Frame(uav=self.uav, seq=s, stamp_s=now, width=w, height=h, pixels=pixels) for s in (0, 1)
            ]
        elif kind == "size":
            for side in (64, 4096):
                big = rng.integers(0, 255, (side, side), dtype=np.uint8)
                frames.append(
                    Frame(uav=self.uav, seq=10**6, stamp_s=now, width=side, height=side, pixels=big)
                )
        elif kind == "uav":
            frames.append(Frame(uav="intruder", seq=10**6, stamp_s=now, width=w, height=h, pixels=pixels))
        elif kind == "future":
            frames.append(Frame(uav=self.uav, seq=10**6, stamp_s=now + 1e5, width=w, height=h, pixels=pixels))
        elif kind in ("settings", "streams"):
            self._jobs(kind)
        elif kind == "sender":
            self._second_sender(pixels)
        if frames:
            # a publisher of its own that blocks rather than drops: the stream's camera publisher drops under
            # congestion, and a 16 MB forged frame lost on a busy host would test the transport, not the gate
            forger = self.session.declare_publisher(
                keys.camera_key(self.uav), congestion_control=zenoh.CongestionControl.BLOCK
            )
            copied = zenoh.SourceInfo(self.camera.id, 0)  # the camera's own sender id, forged
            try:
                for frame in frames:
                    payload, attachment = encode(frame)
                    forger.put(payload, attachment=attachment, source_info=copied)
            finally:
                forger.undeclare()
        self.sent[kind] = self.sent.get(kind, 0) + 1

    def _second_sender(self, pixels: np.ndarray) -> None:
        # blocking, as the forger above: a dropping publisher lost one of the three on a busy host (the load
        # test counted 2 foreign frames of 3 in the loaded suite), which tests the transport, not the gate
        publisher = self.session.declare_publisher(
            keys.camera_key(self.uav), congestion_control=zenoh.CongestionControl.BLOCK
        )
        try:
            seq = self.next_seq()
            for k in range(3):  # three that agree: a restart would be confirmed, another sender is not
                frame = Frame(uav=self.uav, seq=seq + k, stamp_s=time.time(), width=self.width,
                              height=self.height, pixels=pixels)  # fmt: skip
                payload, attachment = encode(frame)
                publisher.put(payload, attachment=attachment, source_info=zenoh.SourceInfo(publisher.id, k))
        finally:
            publisher.undeclare()

    def _jobs(self, kind: str) -> None:
        host = self.spec.hosts[0].name
        wire = YawJobSettings.of(for_frame(YawSettings(), (self.height, self.width))).model_dump(
            mode="json"
        )  # a hostile copy is sent unchecked
        n = 1 if kind == "settings" else 2000
        for i in range(n):
            settings = dict(wire, patch_size_px=100_000) if kind == "settings" else wire
            job = PatchJob.model_construct(
                stream=f"hostile{i}", seq=1, prev_seq=0, settings=settings, indices=np.array([0], np.int32),
                crops=np.zeros((1, 32, 32), np.uint8), prev_indices=np.array([0], np.int32),
                prev_crops=np.zeros((1, 32, 32), np.uint8), budget_s=0.2,
            )  # fmt: skip
            payload, attachment = encode(job)
            key = keys.worker_key(host, 0)
            self.session.get(key, lambda _r: None, payload=payload, attachment=attachment, timeout=1.0)
