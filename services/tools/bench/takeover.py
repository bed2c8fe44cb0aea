"""A hostile participant against a master take-over: forged yaw just before the active master dies.

A standby master continues the yaw from the last one published. The attacker re-publishes the newest
published frame's yaw (its real seq and stamp, 2 rad off) every 5 ms around the moment the active master
is killed: if the standby believed
the forged yaw, every later yaw would be 2 rad (115 deg) off. The evidence: the flight's largest yaw error
against the in-process tracker, the forged yaw sent and how many the standby refused (``yaw_untrusted``).
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import Health, YawEstimate
from common.wire.schema import WireError
from services.runtime.transport import zbytes
from services.tools.bench.hostile import (
    AttackResult,
    YawWatch,
    attacker,
    fly,
    frames_lost,
    max_yaw_error_deg,
    watching,
)
from services.tools.up import LocalCluster

STANDBY = "master/standby/0"
#: how far off the forged yaw is (rad)
FORGED_OFFSET_RAD = 2.0


def start_standby(cluster: LocalCluster) -> None:
    """A second master of the cluster's UAV (``master/standby/0``), alive before it returns (nothing to do
    when it runs already)."""
    if STANDBY in cluster.processes and cluster.processes[STANDBY].poll() is None:
        return
    spec = cluster.spec
    args = ["master", *cluster.transport_args(), "--node", "standby", "--uav", spec.uav, "--topology",
            spec.topology.value, "--balance", spec.balance.value, "--speed", spec.speed.value,
            "--compute" if spec.master_computes else "--no-compute"]  # fmt: skip
    cluster.spawn(STANDBY, args, spec.master_cpus, common_name=f"master.{spec.uav}")
    cluster.wait_alive({STANDBY})


def leader(session: zenoh.Session, uav: str) -> str | None:
    """``master/{node}/{i}`` of the UAV's active master (its election token), None if there is none."""
    for reply in session.liveliness().get(keys.election_all(uav), timeout=2.0):
        key = str(reply.ok.key_expr) if reply.ok is not None else ""
        if "/leader/" in key:
            return "master/" + key.split("/leader/", 1)[1]
    return None


def fly_to_halfway(
    cluster: LocalCluster,
    watch: YawWatch,
    session: zenoh.Session,
    frames: int,
    fps: float,
    slack_s: float,
    yaw_timeout_s: float = 5.0,
) -> tuple[threading.Thread, str | None]:
    """Start a flight of ``frames`` frames (flow-controlled) in a thread, wait until half of them have a yaw,
    and return the thread and the active master then (:func:`leader`, polled for up to 20 s)."""
    flight = threading.Thread(
        target=fly,
        args=(cluster, watch, frames, fps, slack_s + 2 * frames / fps, 1, False, yaw_timeout_s),
        daemon=True,
    )
    flight.start()
    deadline = time.monotonic() + slack_s + frames / fps
    while time.monotonic() < deadline and len(watch.yaw) < frames // 2:
        time.sleep(0.05)
    # polled: on a busy host the attacker's fresh session may not see the election token at once
    # (one run of the suite under load read no leader and killed nothing)
    return flight, poll_leader(session, cluster.spec.uav, lambda active: active is not None, 20.0)


def poll_leader(
    session: zenoh.Session, uav: str, wanted: Callable[[str | None], bool], timeout_s: float
) -> str | None:
    """:func:`leader`, asked again until ``wanted`` of it holds or ``timeout_s`` passed (a query that finds
    no token returns at once: it pauses between them); the last answer."""
    active, deadline = leader(session, uav), time.monotonic() + timeout_s
    while not wanted(active) and time.monotonic() < deadline:
        time.sleep(0.05)
        active = leader(session, uav)
    return active


def counters_of(session: zenoh.Session, name: str) -> dict[str, int]:
    role, node, index = name.split("/")
    for reply in session.get(keys.health_key(role, node, int(index)), timeout=2.0):
        if reply.ok is not None:
            try:
                return decode(zbytes(reply.ok.payload), zbytes(reply.ok.attachment), Health).counters
            except WireError:
                return {}
    return {}


def attack_forged_yaw_takeover(
    cluster: LocalCluster, profile: str, frames: int, fps: float, reference_rad: np.ndarray
) -> AttackResult:
    """Forge the newest published yaw (every 5 ms) while the active master is killed halfway through a
    flight (the cluster's master dies: run it last; the standby goes on)."""
    uav = cluster.spec.uav
    start_standby(cluster)
    forged = 0
    killed = None
    with watching(cluster, uav) as watch, attacker(cluster) as session:
        flight, active = fly_to_halfway(cluster, watch, session, frames, fps, 60.0)
        publisher = session.declare_publisher(keys.yaw_key(uav))
        stop = threading.Event()

        def forge() -> None:  # the newest published frame's yaw, 2 rad off, every 5 ms around the kill
            nonlocal forged
            while not stop.wait(0.005):
                seq = max(list(watch.yaw), default=None)
                if seq is None:
                    continue
                forgery = YawEstimate(
                    uav=uav, seq=seq, stamp_s=watch.stamps[seq], delta_yaw_rad=0.0,
                    yaw_rad=watch.yaw[seq] + FORGED_OFFSET_RAD, inlier_count=40, patch_count=40,
                    confidence=1.0, low_confidence=False, method="patches",
                )  # fmt: skip
                payload, attachment = encode(forgery)
                publisher.put(payload, attachment=attachment)
                forged += 1

        forger = threading.Thread(target=forge, daemon=True)
        forger.start()
        time.sleep(0.3)
        if active is not None and active in cluster.processes:
            cluster.signal(active, signal.SIGKILL)
            killed = active
        time.sleep(1.0)  # the take-over happens meanwhile
        stop.set()
        forger.join(2.0)
        flight.join(60.0 + 2 * frames / fps)
        survivor = STANDBY if killed != STANDBY else "master/master/0"
        refused = counters_of(session, survivor).get("yaw_untrusted", 0)
    error = max_yaw_error_deg(watch, reference_rad)
    evidence = {
        "forged_yaw_sent": forged,
        "killed": killed,
        "refused_by_standby": refused,
        "yaw_error_deg": error,
        "frames": frames,
        "frames_lost": frames_lost(watch, frames),
    }
    return AttackResult("forged_yaw_before_takeover", profile, not error < 1.0, evidence)
