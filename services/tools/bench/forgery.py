"""Forged outputs and sensor inputs from a participant without the role for them (``bench security``'s
``forged_outputs``): yaw, attitude and pose/vo messages a client would believe, an IMU sample stamped 1e4 s
ahead (one locked the master's gyro prior out, issue 27) and a range reading. The evidence is what an
ordinary subscriber decodes: in the secure profile access control delivers none of them."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zenoh

from common.wire import keys
from common.wire.codec import decode, encode
from common.wire.messages import AttitudeEstimate, ImuSample, PoseEstimate, RangeSample, YawEstimate
from common.wire.schema import WireError, WireModel
from services.runtime.transport import open_session, zbytes
from services.tools.bench.hostile import FORGED_SEQ0, FORGED_SOURCE, AttackResult, attacker, outsider_probe
from services.tools.up import LocalCluster

#: the forged range reading (m): no real flight of the tests reads it
FORGED_RANGE_M = 50.0
#: a forged IMU sample is stamped this far ahead (s)
FORGED_IMU_AHEAD_S = 1e4


def is_forged(message: Any) -> bool:
    """Whether a decoded message carries a forger's marker (seq, stamp far ahead, range)."""
    if isinstance(message, ImuSample):
        return message.stamp_s > time.time() + FORGED_IMU_AHEAD_S / 2
    if isinstance(message, RangeSample):
        return message.range_m == FORGED_RANGE_M
    return int(getattr(message, "seq", 0)) >= FORGED_SEQ0


class ForgedCounter:
    """Counts decoded messages of a key that carry the forged marker (what ordinary subscribers accept)."""

    def __init__(self, session: zenoh.Session, key: str, expected: type[Any]) -> None:
        self.accepted = 0
        self.total = 0
        self._expected = expected
        self._sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.total += 1
        try:
            message = decode(zbytes(sample.payload), zbytes(sample.attachment), self._expected)
        except WireError:
            return
        if is_forged(message):
            self.accepted += 1

    def close(self) -> None:
        self._sub.undeclare()


def forged_messages(uav: str, seq: int) -> dict[str, Any]:
    """A valid yaw, attitude and pose/vo message of ``uav``, and sensor inputs: an IMU sample stamped 1e4 s
    ahead (one locked the master's gyro prior out, issue 27) and a range reading (the forger's payloads)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    return {
        keys.imu_key(uav): ImuSample(
            uav=uav, stamp_s=time.time() + FORGED_IMU_AHEAD_S, gyro_rad_s=np.array([0.0, 0.0, 5.0]),
            accel_m_s2=np.array([0.0, 0.0, 9.81]),
        ),
        keys.range_key(uav): RangeSample(uav=uav, stamp_s=time.time(), range_m=FORGED_RANGE_M),
        keys.yaw_key(uav): YawEstimate(
            uav=uav, seq=seq, stamp_s=time.time(), delta_yaw_rad=1.0, yaw_rad=3.0, inlier_count=40,
            patch_count=40, confidence=1.0, low_confidence=False, method="patches",
        ),
        keys.attitude_key(uav): AttitudeEstimate(
            uav=uav, seq=seq, stamp_s=time.time(), q_world_body=q, covariance=np.eye(3) * 1e-6
        ),
        keys.pose_vo_key(uav): PoseEstimate(
            uav=uav, seq=seq, stamp_s=time.time(), p_world_body_m=np.array([100.0, 0.0, 5.0]),
            q_world_body=q, covariance=np.eye(6) * 1e-6, source=FORGED_SOURCE,
        ),
    }  # fmt: skip


def attack_forged_outputs(cluster: LocalCluster, profile: str, uav: str, count: int = 40) -> AttackResult:
    """Forge yaw, attitude and pose/vo, and IMU and range inputs; count what an ordinary subscriber (a client)
    decodes."""
    types: dict[str, type[WireModel]] = {
        keys.yaw_key(uav): YawEstimate,
        keys.attitude_key(uav): AttitudeEstimate,
    }
    types[keys.pose_vo_key(uav)] = PoseEstimate
    types[keys.imu_key(uav)] = ImuSample
    types[keys.range_key(uav)] = RangeSample
    with open_session(cluster.observer_transport()) as observer:
        counters = {key: ForgedCounter(observer, key, t) for key, t in types.items()}
        time.sleep(0.3)
        with attacker(cluster) as session:
            publishers = {key: session.declare_publisher(key) for key in types}
            for i in range(count):
                for key, message in forged_messages(uav, FORGED_SEQ0 + i).items():
                    payload, attachment = encode(message)
                    publishers[key].put(payload, attachment=attachment)
                time.sleep(0.005)
            time.sleep(0.5)
        for c in counters.values():
            c.close()
    delivered = {key.split(f"/{uav}/", 1)[1]: c.accepted for key, c in counters.items()}
    evidence: dict[str, Any] = {"sent_each": count, "delivered": delivered, **outsider_probe(cluster)}
    return AttackResult("forged_outputs", profile, sum(delivered.values()) > 0, evidence)
