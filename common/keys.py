"""Every Zenoh key expression of capataz, in one place.

| key expression                          | kind       | payload                       |
| --------------------------------------- | ---------- | ----------------------------- |
| ``capataz/uav/{uav}/camera``            | pub/sub    | Frame                         |
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

import re
from dataclasses import dataclass
from enum import StrEnum
from functools import partial

from common.errors import InputError

ROOT = "capataz"
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")


class Role(StrEnum):
    """Roles of services (the ``{role}`` part of liveliness, stats and health keys)."""

    CAMERA = "camera"
    MASTER = "master"
    FOREMAN = "foreman"
    WORKER = "worker"
    ROUTER = "router"
    ESTIMATOR = "estimator"
    LOCALIZER = "localizer"
    RECORDER = "recorder"
    VIEWER = "viewer"
    BRIDGE = "bridge"


def check_name(value: str, what: str = "name") -> str:
    """A key chunk: letters, digits, ``_ . -`` only (no ``/``, ``*``, ``$``, ``?``, ``#``)."""
    if not isinstance(value, str) or not _NAME.match(value):
        raise InputError(f"{what} must match [A-Za-z0-9_.-]+, got {value!r}")
    return value


def _index(i: int) -> int:
    if isinstance(i, bool) or not isinstance(i, int) or i < 0:
        raise InputError(f"index must be a non-negative int, got {i!r}")
    return i


def uav_key(uav: str, topic: str) -> str:
    return f"{ROOT}/uav/{check_name(uav, 'uav')}/{topic}"


# the streams of one UAV (the table above): ``camera_key("uav0") == "capataz/uav/uav0/camera"``
camera_key = partial(uav_key, topic="camera")
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
    return f"{ROOT}/node/{check_name(node, 'node')}/worker/{_index(i)}"


def _member_key(kind: str, role: str | Role, node: str, i: int) -> str:
    """``capataz/{kind}/{role}/{node}/{i}``: a service instance's liveliness token, stats or health key."""
    return f"{ROOT}/{kind}/{Role(role).value}/{check_name(node, 'node')}/{_index(i)}"


alive_key = partial(_member_key, "alive")
stats_key = partial(_member_key, "stats")
health_key = partial(_member_key, "health")


#: everything capataz publishes (what ``capataz record`` subscribes to)
ALL = f"{ROOT}/**"


def master_candidate_key(uav: str, node: str, i: int) -> str:
    """Liveliness token of a master that can serve ``uav`` (active or standby)."""
    return f"{ROOT}/elect/{check_name(uav, 'uav')}/candidate/{check_name(node, 'node')}/{_index(i)}"


def master_leader_key(uav: str, node: str, i: int) -> str:
    """Liveliness token of the one active master of ``uav``."""
    return f"{ROOT}/elect/{check_name(uav, 'uav')}/leader/{check_name(node, 'node')}/{_index(i)}"


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


@dataclass(frozen=True, order=True)
class MemberId:
    """A service instance: ``role/node/i``; its name is used in shares and reports."""

    role: Role
    node: str
    index: int

    @property
    def name(self) -> str:
        return f"{self.role.value}/{self.node}/{self.index}"

    @classmethod
    def from_name(cls, name: str) -> MemberId:
        """Inverse of :attr:`name` (``role/node/i``); InputError otherwise."""
        parts = str(name).split("/")
        if len(parts) != 3:
            raise InputError(f"not a member name (role/node/i): {name!r}")
        try:
            role, index = Role(parts[0]), int(parts[2])
        except ValueError as exc:
            raise InputError(f"bad member name {name!r}: {exc}") from None
        return cls(role, check_name(parts[1], "node"), _index(index))

    @property
    def work_key(self) -> str:
        """Where a dispatcher sends this member work (foreman or worker queryable)."""
        if self.role is Role.FOREMAN:
            return foreman_key(self.node)
        if self.role is Role.WORKER:
            return worker_key(self.node, self.index)
        raise InputError(f"{self.name} takes no work")


def work_key_of(member: str) -> str:
    """The work queryable of the member named ``role/node/i`` (what dispatchers address)."""
    return MemberId.from_name(member).work_key


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
    return MemberId(role, check_name(parts[3], "node"), _index(index))
