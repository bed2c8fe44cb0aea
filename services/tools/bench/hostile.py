"""Hostile participants: each attack of issue 12 against a running local cluster (open or secure profile).

Every attack connects its own session to the cluster's router (as a peer, so it may also link directly to
the other peers), does its harm and returns an :class:`AttackResult`: ``succeeded`` and the evidence
(messages delivered, crops received, yaw error caused, frames lost). In the secure profile the attacker
holds a *valid* certificate of the unprivileged ``client`` role (the strongest outsider: it passes mutual
TLS, so only access control stops it); :func:`outsider_probe` checks that a participant without a
certificate of the CA cannot connect at all.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import zenoh

from common.members import Role
from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import (
    BlockJob,
    BlockResult,
    Frame,
    YawEstimate,
    YawJobSettings,
)
from common.wire.schema import WireError
from common.yaw import YawSettings, make_patch_grid
from services.runtime.transport import TransportError, TransportSettings, open_session, zbytes
from services.tools.up import LocalCluster

logger = logging.getLogger(__name__)
#: a seq no real camera reaches in a test: forged frames are recognisable in the published yaw
FORGED_SEQ0 = 1_000_000
FORGED_SOURCE = "forged"


@dataclass
class AttackResult:
    name: str
    profile: str
    succeeded: bool
    evidence: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def attacker_transport(cluster: LocalCluster, holder: str = "client") -> TransportSettings:
    """A peer connected to the router; in the secure profile it holds the ``holder`` certificate (the
    read-only ``client``'s, or a stolen one of another role or node)."""
    env = cluster.secure.environment(holder) if cluster.secure else {}
    return TransportSettings.from_env(
        environ=env,
        connect=(cluster.router,),
        listen=(f"{cluster.scheme}/127.0.0.1:0",),
        lease_ms=cluster.lease_ms,
    )


@contextmanager
def attacker(cluster: LocalCluster, holder: str = "client") -> Iterator[zenoh.Session]:
    with open_session(attacker_transport(cluster, holder)) as session:
        time.sleep(0.5)  # links to the router and the peers it learns about
        yield session


def outsider_probe(cluster: LocalCluster, timeout_ms: int = 2000) -> dict[str, Any]:
    """Connect as a client without a certificate of the cluster's CA: refused in the secure profile."""
    env: dict[str, str] = {}
    if cluster.secure is not None:  # it knows the CA (public) but has no certificate signed by it
        env = {"CAPATAZ_ZENOH_TLS_CA": cluster.secure.environment("client")["CAPATAZ_ZENOH_TLS_CA"]}
    settings = TransportSettings.from_env(
        environ=env, mode="client", connect=(cluster.router,), listen=(), connect_timeout_ms=timeout_ms
    )
    try:
        with open_session(settings):
            return {"outsider_connected": True}
    except TransportError as exc:
        return {"outsider_connected": False, "refused": str(exc).splitlines()[0][:160]}


@contextmanager
def fake_member(
    session: zenoh.Session, role: Role, node: str, index: int = 0, answer: Any = None
) -> Iterator[dict[str, int]]:
    """A liveliness token and a work queryable of ``role`` on ``node``; counts jobs and crop bytes.

    ``answer(job) -> BlockResult | None`` replies (a fake foreman); without it the jobs are kept unanswered.
    """
    seen = {"jobs": 0, "crop_bytes": 0, "declared": 0}
    lock = threading.Lock()
    key = keys.foreman_key(node) if role is Role.FOREMAN else keys.worker_key(node, index)

    def on_query(query: zenoh.Query) -> None:
        with lock:
            seen["jobs"] += 1
            seen["crop_bytes"] += len(zbytes(query.payload) or b"")
        if answer is None:
            query.drop()
            return
        try:
            job = decode(zbytes(query.payload), zbytes(query.attachment), BlockJob)
            payload, attachment = encode(answer(job))
            query.reply(query.key_expr, payload, attachment=attachment)
        except Exception as exc:  # the attacker's own bugs must not hang the test
            logger.debug("fake member: %s", exc)
        finally:
            query.drop()

    queryable = session.declare_queryable(key, on_query, complete=True)
    token = session.liveliness().declare_token(keys.alive_key(role, node, index))
    seen["declared"] = 1
    try:
        yield seen
    finally:
        token.undeclare()
        queryable.undeclare()


def wrong_shifts_answer(rotation_deg: float, frame_shape: tuple[int, int]) -> Any:
    """A fake foreman's reply: every patch valid, shifts of a rotation by ``rotation_deg`` per frame."""
    theta = np.radians(rotation_deg)
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    grids: dict[YawJobSettings, Any] = {}

    def answer(job: BlockJob) -> BlockResult:
        if job.settings not in grids:
            grids[job.settings] = make_patch_grid(frame_shape, job.settings.yaw_settings)
        centres = grids[job.settings].centres_px[job.indices]
        middle = np.array([frame_shape[1] / 2.0, frame_shape[0] / 2.0])
        shift = (centres - middle) @ rot.T + middle - centres
        n = int(job.indices.size)
        return BlockResult(
            stream=job.stream, seq=job.seq, prev_seq=job.prev_seq, member="foreman/evil/0",
            indices=job.indices, shift_px=shift, confidence=np.full(n, 50.0), peak=np.ones(n),
            valid=np.ones(n, dtype=bool), compute_s=1e-4, members={"foreman/evil/0": n},
            speeds={"foreman/evil/0": 1e6},
        )  # fmt: skip

    return answer


class YawWatch:
    """The published yaw of a UAV by seq (real frames only; ``measured``: not a stream's initial one). The
    first yaw of a seq is kept: a forged one re-using a published seq comes later and is only counted."""

    def __init__(self, session: zenoh.Session, uav: str) -> None:
        self.yaw: dict[int, float] = {}
        self.stamps: dict[int, float] = {}
        self.measured: set[int] = set()
        self.forged_seen = 0
        self.repeated = 0
        self._sub = session.declare_subscriber(keys.yaw_key(uav), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            e = decode(zbytes(sample.payload), zbytes(sample.attachment), YawEstimate)
        except WireError:
            return
        if e.seq >= FORGED_SEQ0:
            self.forged_seen += 1
        elif e.seq in self.yaw:
            self.repeated += 1
        else:
            self.yaw[e.seq], self.stamps[e.seq] = e.yaw_rad, e.stamp_s
            if e.method != "initial":
                self.measured.add(e.seq)

    def close(self) -> None:
        self._sub.undeclare()


def fly(
    cluster: LocalCluster,
    watch: YawWatch,
    frames: int,
    fps: float,
    timeout_s: float,
    in_flight: int = 0,
    sensors: bool = False,
    yaw_timeout_s: float = 5.0,
) -> float:
    """Run the camera's simulated flight at ``fps`` (``in_flight`` > 0: flow-controlled, a frame waiting at
    most ``yaw_timeout_s`` for its yaw; ``sensors``: with IMU and rangefinder) and wait for its last yaw;
    wall seconds. A camera still running at ``timeout_s`` is stopped (the next flight starts clean)."""
    t0 = time.monotonic()
    args = ["--frames", str(frames), "--fps", str(fps), "--in-flight", str(in_flight)]
    args += ["--yaw-timeout", str(yaw_timeout_s)]
    camera = cluster.start_camera(args if sensors else [*args, "--no-sensors"])
    deadline = t0 + timeout_s
    while time.monotonic() < deadline and cluster.processes[camera].poll() is None:
        time.sleep(0.1)
    if cluster.processes[camera].poll() is None:
        logger.warning("the camera's flight outlasted %.0f s: stopped", timeout_s)
        cluster.signal(camera, signal.SIGTERM)
        cluster.processes[camera].wait(10.0)
    last = -1
    while time.monotonic() < deadline and watch.yaw and max(watch.yaw) != last:  # the last frames settle
        last = max(watch.yaw)
        time.sleep(0.5)
    return time.monotonic() - t0


def frames_lost(watch: YawWatch, frames: int) -> int:
    """Real frames (after the first, which starts the stream) without a measured yaw."""
    return frames - 1 - sum(1 for s in watch.measured if 0 < s < frames)


def max_yaw_error_deg(watch: YawWatch, reference_rad: np.ndarray) -> float:
    """:func:`max_yaw_error_deg_of` the yaw a watch saw."""
    return max_yaw_error_deg_of(watch.yaw, reference_rad)


def max_yaw_error_deg_of(yaw: dict[int, float], reference_rad: np.ndarray) -> float:
    """Largest error of a flight's yaw by seq against the reference, both taken relative to the flight's
    first published frame: on a running cluster a new flight (the camera restarted from seq 0) is a new
    stream epoch whose yaw continues the last published one (common.streams), not a reset to the
    reference's 0."""
    seqs = [s for s in yaw if s < reference_rad.size]
    if not seqs:
        return float("nan")
    start = min(seqs)
    offset = yaw[start] - reference_rad[start]
    return float(np.degrees(max(abs(yaw[s] - offset - reference_rad[s]) for s in seqs)))


def reference_yaw_rad(frames: int) -> np.ndarray:
    """In-process yaw of every frame of the camera's simulated flight (what the cluster must publish: its
    master gets the flight's rig and IMU stream, :func:`~services.tools.demo_yaw.track_frames`)."""
    from services.camera import CameraSettings, simulated_flight
    from services.tools.demo_yaw import track_frames

    flight = simulated_flight(CameraSettings(frames=frames))
    return track_frames((flight.frame(k) for k in range(frames)), YawSettings(), flight).yaw_rad


@contextmanager
def watching(cluster: LocalCluster, uav: str) -> Iterator[YawWatch]:
    with open_session(cluster.observer_transport()) as session:
        watch = YawWatch(session, uav)
        try:
            yield watch
        finally:
            watch.close()


def attack_fake_worker(
    cluster: LocalCluster,
    profile: str,
    frames: int,
    fps: float,
    holder: str = "client",
    role: Role = Role.WORKER,
) -> AttackResult:
    """A ``role`` token and work queryable on host h1 (worker 9; a foreman on h1's own block key), from a
    session holding ``holder``'s certificate (e.g. ``worker.h2``: another node's): does it get crops?"""
    host = cluster.spec.hosts[0].name
    with (
        watching(cluster, cluster.spec.uav) as watch,
        attacker(cluster, holder) as session,
        fake_member(session, role, host, index=9 if role is Role.WORKER else 0) as seen,
    ):
        fly(cluster, watch, frames, fps, timeout_s=60.0 + frames / fps)
    evidence = {"jobs_received": seen["jobs"], "crop_bytes_received": seen["crop_bytes"], "frames": frames,
                "frames_lost": frames_lost(watch, frames), "holder": holder}  # fmt: skip
    name = "fake_worker_crops" if holder == "client" else f"{role.value}_on_{host}_as_{holder}"
    return AttackResult(name, profile, seen["jobs"] > 0, evidence)


def attack_fake_foreman(
    cluster: LocalCluster, profile: str, frames: int, fps: float, reference_rad: np.ndarray
) -> AttackResult:
    """A foreman that answers at once with the shifts of a 2 deg/frame rotation (balancing rewards speed)."""
    shape = (480, 752)
    with watching(cluster, cluster.spec.uav) as watch, attacker(cluster) as session:
        answer = wrong_shifts_answer(2.0, shape)
        with fake_member(session, Role.FOREMAN, "evil", answer=answer) as seen:
            wall = fly(cluster, watch, frames, fps, timeout_s=60.0 + 2 * frames / fps, in_flight=1)
    error = max_yaw_error_deg(watch, reference_rad)
    evidence = {"jobs_answered": seen["jobs"], "yaw_error_deg": error, "frames": frames, "seconds": wall,
                "frames_lost": frames_lost(watch, frames)}  # fmt: skip
    return AttackResult("fake_foreman_wrong_shifts", profile, not error < 1.0, evidence)


def attack_frame_flood(
    cluster: LocalCluster, profile: str, frames: int, fps: float, flood_fps: float = 100.0
) -> AttackResult:
    """Forged frames at ``flood_fps`` on the camera key while the real camera flies at ``fps``."""
    h, w = 480, 752
    rng = np.random.default_rng(7)
    noise = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    stop = threading.Event()
    sent = [0]
    with watching(cluster, cluster.spec.uav) as watch, attacker(cluster) as session:
        publisher = session.declare_publisher(keys.camera_key(cluster.spec.uav))

        def flood() -> None:
            while not stop.wait(1.0 / flood_fps):
                frame = Frame(uav=cluster.spec.uav, seq=FORGED_SEQ0 + sent[0], stamp_s=time.time(),
                              width=w, height=h, pixels=np.roll(noise, sent[0], axis=1))  # fmt: skip
                payload, attachment = encode(frame)
                publisher.put(payload, attachment=attachment)
                sent[0] += 1

        thread = threading.Thread(target=flood, daemon=True)
        thread.start()
        try:
            fly(cluster, watch, frames, fps, timeout_s=60.0 + frames / fps)
        finally:
            stop.set()
            thread.join(2.0)
    lost = frames_lost(watch, frames)
    evidence = {"forged_sent": sent[0], "frames": frames, "frames_lost": lost,
                "lost_pct": 100.0 * lost / max(1, frames - 1),
                "forged_yaw_published": watch.forged_seen}  # fmt: skip
    return AttackResult("forged_frame_flood", profile, lost > 0.01 * (frames - 1), evidence)


def attack_liveliness_flood(
    cluster: LocalCluster, profile: str, frames: int, fps: float, tokens: int = 100
) -> AttackResult:
    """``tokens`` fake foreman liveliness tokens (no queryables) while the real camera flies."""
    with watching(cluster, cluster.spec.uav) as watch, attacker(cluster) as session:
        declared = [session.liveliness().declare_token(keys.alive_key(Role.FOREMAN, f"flood{i}", 0))
                    for i in range(tokens)]  # fmt: skip
        try:
            fly(cluster, watch, frames, fps, timeout_s=60.0 + frames / fps)
        finally:
            for token in declared:
                token.undeclare()
    lost = frames_lost(watch, frames)
    evidence = {"tokens": tokens, "frames": frames, "frames_lost": lost,
                "lost_pct": 100.0 * lost / max(1, frames - 1)}  # fmt: skip
    return AttackResult("liveliness_flood", profile, lost > 0.01 * (frames - 1), evidence)
