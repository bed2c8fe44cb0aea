"""Hostile participants against the masters' election (issue 27): forged liveliness tokens.

- **Forged leader**: the attacker holds a leader token named before the real master (``a/0``), so by the
  election's rule the real master yields while it is held. Evidence: frames without a measured yaw during a
  flight flown while the token is held.
- **Forged candidate**: the attacker holds a candidate token named before the standby; the active master is
  killed halfway through a flight, and a standby that believed the token would wait for ``a/0`` to lead,
  forever. Evidence: frames lost after the kill. The killed master is started again (it stands by), so the
  cluster keeps two masters for what runs after.

In the secure profile only a master's certificate may declare election tokens (``services.runtime.acl``): the
router never delivers the attacker's, and nothing is lost. In the open profile both attacks succeed: that is
one of the open profile's documented limits.
"""

from __future__ import annotations

import signal
import time

from common.wire import keys
from services.runtime.transport import open_session
from services.tools.bench.hostile import AttackResult, attacker, fly, frames_lost, watching
from services.tools.bench.takeover import fly_to_halfway, poll_leader, start_standby
from services.tools.up import LocalCluster

#: the forged master's ``node/index``: sorts before every real master's (``master/0``, ``standby/0``)
FORGED_NODE = "a"
#: more frames lost than this is a successful attack (a kill may cost the frame in flight)
LOST_ALLOWED = 1
#: a frame waits this long for its yaw (s): where an attack stops the yaw, the flight still ends in time
YAW_TIMEOUT_S = 0.5


def attack_forged_leader(cluster: LocalCluster, profile: str, frames: int, fps: float) -> AttackResult:
    """Fly ``frames`` frames while a forged leader token is held; the token is released afterwards."""
    uav = cluster.spec.uav
    with watching(cluster, uav) as watch, attacker(cluster) as session:
        token = session.liveliness().declare_token(keys.master_leader_key(uav, FORGED_NODE, 0))
        # seen from another session (the attacker's own always lists its own token), polled: on a busy host
        # a delivered token takes a while to be seen
        forged = f"master/{FORGED_NODE}/0"
        with open_session(cluster.observer_transport()) as observer:
            seen_as_leader = poll_leader(observer, uav, lambda active: active == forged, 3.0) == forged
        time.sleep(0.5)  # the masters' next loop turn sees the token (when it is delivered)
        fly(cluster, watch, frames, fps, 30.0 + 2 * frames / fps, 1, yaw_timeout_s=YAW_TIMEOUT_S)
        token.undeclare()
        lost = frames_lost(watch, frames)
    evidence = {"frames": frames, "frames_lost": lost, "forged_leader_visible": seen_as_leader}
    return AttackResult("forged_leader_token", profile, lost > LOST_ALLOWED, evidence)


def attack_forged_candidate(cluster: LocalCluster, profile: str, frames: int, fps: float) -> AttackResult:
    """Hold a forged candidate token, kill the active master halfway through a flight, count the frames lost
    after the kill; then release the token and start the killed master again as a standby."""
    uav = cluster.spec.uav
    start_standby(cluster)
    killed = None
    with watching(cluster, uav) as watch, attacker(cluster) as session:
        token = session.liveliness().declare_token(keys.master_candidate_key(uav, FORGED_NODE, 0))
        flight, active = fly_to_halfway(cluster, watch, session, frames, fps, 30.0, YAW_TIMEOUT_S)
        killed_at_seq = max(watch.yaw, default=-1)
        if active is not None and active in cluster.processes:
            cluster.signal(active, signal.SIGKILL)
            killed = active
        flight.join(30.0 + 2 * frames / fps)
        token.undeclare()
        after_kill = frames - 1 - killed_at_seq  # the frames flown after the kill
        lost_after_kill = after_kill - sum(1 for s in watch.measured if killed_at_seq < s < frames)
        lost = frames_lost(watch, frames)
    if killed is not None:  # the killed master comes back as a standby
        cluster.respawn(killed)
        cluster.wait_alive({killed})
    evidence = {
        "frames": frames,
        "killed": killed,
        "killed_at_seq": killed_at_seq,
        "frames_lost": lost,
        "frames_lost_after_kill": lost_after_kill,
    }
    return AttackResult("forged_candidate_token", profile, lost > LOST_ALLOWED, evidence)
