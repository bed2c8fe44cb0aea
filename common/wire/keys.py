"""Every Zenoh key expression of capataz, in one place.

| key expression                          | kind       | payload                       |
| --------------------------------------- | ---------- | ----------------------------- |
| ``capataz/uav/{uav}/camera``            | pub/sub    | Frame                         |
| ``capataz/uav/{uav}/rig``               | pub/sub    | RigMessage                    |
| ``capataz/uav/{uav}/imu``               | pub/sub    | ImuSample                     |
| ``capataz/uav/{uav}/range``             | pub/sub    | RangeSample                   |
| ``capataz/uav/{uav}/yaw``               | pub/sub    | YawEstimate                   |
| ``capataz/uav/{uav}/attitude``          | pub/sub    | AttitudeEstimate              |
| ``capataz/uav/{uav}/pose/vo``, ``/pf``  | pub/sub    | PoseEstimate                  |
| ``capataz/uav/{uav}/truth``             | pub/sub    | PoseEstimate (simulated only) |
| ``capataz/node/{node}/foreman``         | queryable  | BlockJob -> BlockResult       |
| ``capataz/node/{node}/worker/{i}``      | queryable  | PatchJob -> PatchResult       |
| ``capataz/alive/{role}/{node}/{i}``     | liveliness | membership                    |
| ``capataz/stats/{role}/{node}/{i}``     | pub/sub    | Stats                         |
| ``capataz/health/{role}/{node}/{i}``    | queryable  | (none) -> Health              |
"""

from __future__ import annotations

from functools import partial

from common.errors import InputError
from common.members import MemberId, Role, check_index, check_name

ROOT = "capataz"


def uav_key(uav: str, topic: str) -> str:
    return f"{ROOT}/uav/{check_name(uav, 'uav')}/{topic}"


# the streams of one UAV (the table above): ``camera_key("uav0") == "capataz/uav/uav0/camera"``
camera_key = partial(uav_key, topic="camera")
#: the stream's camera rig (RigMessage), beside its frames; each Frame carries its ``rig_id``
rig_key = partial(uav_key, topic="rig")
imu_key = partial(uav_key, topic="imu")
range_key = partial(uav_key, topic="range")
yaw_key = partial(uav_key, topic="yaw")
attitude_key = partial(uav_key, topic="attitude")
pose_vo_key = partial(uav_key, topic="pose/vo")
pose_pf_key = partial(uav_key, topic="pose/pf")
#: ground truth of a simulated flight (PoseEstimate, source ``truth``), published by the camera
truth_key = partial(uav_key, topic="truth")


def foreman_key(node: str) -> str:
    return f"{ROOT}/node/{check_name(node, 'node')}/foreman"


def worker_key(node: str, i: int) -> str:
    return f"{ROOT}/node/{check_name(node, 'node')}/worker/{check_index(i)}"


def _member_key(kind: str, role: str | Role, node: str, i: int) -> str:
    """``capataz/{kind}/{role}/{node}/{i}``: a service instance's liveliness token, stats or health key."""
    return f"{ROOT}/{kind}/{Role(role).value}/{check_name(node, 'node')}/{check_index(i)}"


alive_key = partial(_member_key, "alive")
stats_key = partial(_member_key, "stats")
health_key = partial(_member_key, "health")


#: everything capataz publishes (what ``capataz record`` subscribes to)
ALL = f"{ROOT}/**"


def master_candidate_key(uav: str, node: str, i: int) -> str:
    """Liveliness token of a master that can serve ``uav`` (active or standby)."""
    return f"{ROOT}/elect/{check_name(uav, 'uav')}/candidate/{check_name(node, 'node')}/{check_index(i)}"


def master_leader_key(uav: str, node: str, i: int) -> str:
    """Liveliness token of the one active master of ``uav``."""
    return f"{ROOT}/elect/{check_name(uav, 'uav')}/leader/{check_name(node, 'node')}/{check_index(i)}"


def election_all(uav: str) -> str:
    """Every candidate and leader token of ``uav``'s masters."""
    return f"{ROOT}/elect/{check_name(uav, 'uav')}/**"


#: every liveliness token / every stats publication / every health queryable
ALIVE_ALL = f"{ROOT}/alive/**"
STATS_ALL = f"{ROOT}/stats/**"
HEALTH_ALL = f"{ROOT}/health/**"


def alive_role(role: str | Role) -> str:
    """All liveliness tokens of one role, e.g. ``capataz/alive/worker/**``."""
    return f"{ROOT}/alive/{Role(role).value}/**"


def alive_node_workers(node: str) -> str:
    """Liveliness tokens of the workers of one node."""
    return f"{ROOT}/alive/{Role.WORKER.value}/{check_name(node, 'node')}/*"


def work_key(member: MemberId) -> str:
    """Where a dispatcher sends ``member`` work (foreman or worker queryable)."""
    if member.role is Role.FOREMAN:
        return foreman_key(member.node)
    if member.role is Role.WORKER:
        return worker_key(member.node, member.index)
    raise InputError(f"{member.name} takes no work")


def work_key_of(member: str) -> str:
    """The work queryable of the member named ``role/node/i`` (what dispatchers address)."""
    return work_key(MemberId.from_name(member))


def parse_alive_key(key: str) -> MemberId:
    """``capataz/alive/{role}/{node}/{i}`` -> :class:`MemberId`; InputError otherwise."""
    parts = str(key).split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[1] != "alive":
        raise InputError(f"not a liveliness key: {key!r}")
    try:
        role = Role(parts[2])
        index = int(parts[4])
    except ValueError as exc:
        raise InputError(f"bad liveliness key {key!r}: {exc}") from None
    return MemberId(role, check_name(parts[3], "node"), check_index(index))
