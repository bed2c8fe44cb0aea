"""Key expressions: built in one place, names validated, liveliness keys parsed back."""

from __future__ import annotations

import pytest

from common.errors import InputError
from common.members import MemberId, Role
from common.wire import keys


def test_key_table() -> None:
    assert keys.camera_key("uav0") == "capataz/uav/uav0/camera"
    assert keys.rig_key("uav0") == "capataz/uav/uav0/rig"
    assert keys.imu_key("a") == "capataz/uav/a/imu" and keys.range_key("a") == "capataz/uav/a/range"
    assert keys.yaw_key("a") == "capataz/uav/a/yaw" and keys.attitude_key("a") == "capataz/uav/a/attitude"
    assert (
        keys.pose_vo_key("a") == "capataz/uav/a/pose/vo" and keys.pose_pf_key("a") == "capataz/uav/a/pose/pf"
    )
    assert keys.foreman_key("h1") == "capataz/node/h1/foreman"
    assert keys.worker_key("h1", 3) == "capataz/node/h1/worker/3"
    assert keys.alive_key("worker", "h1", 3) == "capataz/alive/worker/h1/3"
    assert keys.stats_key(Role.MASTER, "m", 0) == "capataz/stats/master/m/0"
    assert keys.health_key("foreman", "h2", 0) == "capataz/health/foreman/h2/0"
    assert keys.alive_node_workers("h1") == "capataz/alive/worker/h1/*"


@pytest.mark.parametrize("bad", ["", "a/b", "*", "a b", "x$", "**"])
def test_names_that_would_change_the_key_are_rejected(bad: str) -> None:
    with pytest.raises(InputError):
        keys.camera_key(bad)
    with pytest.raises(InputError):
        keys.worker_key(bad, 0)


def test_liveliness_keys_round_trip_and_garbage_is_rejected() -> None:
    member = keys.parse_alive_key(keys.alive_key("foreman", "h2", 0))
    assert member == MemberId(Role.FOREMAN, "h2", 0)
    assert member.name == "foreman/h2/0" and keys.work_key(member) == keys.foreman_key("h2")
    assert keys.work_key(keys.parse_alive_key("capataz/alive/worker/h1/4")) == keys.worker_key("h1", 4)
    for bad in ("capataz/alive/boss/h1/0", "capataz/alive/worker/h1/x", "capataz/stats/worker/h1/0", "a/b"):
        with pytest.raises(InputError):
            keys.parse_alive_key(bad)
    with pytest.raises(InputError):
        keys.work_key(keys.parse_alive_key("capataz/alive/camera/c/0"))
    with pytest.raises(InputError):
        keys.worker_key("h1", -1)


def test_member_names_round_trip_to_their_work_keys_and_garbage_is_rejected() -> None:
    worker = MemberId(Role.WORKER, "h2", 3)
    assert MemberId.from_name(worker.name) == worker
    assert keys.work_key_of("worker/h2/3") == keys.worker_key("h2", 3)
    assert keys.work_key_of("foreman/h1/0") == keys.foreman_key("h1")
    for bad in ("worker/h2", "boss/h2/0", "worker/h2/x", "worker/h 2/0", "worker/h2/-1"):
        with pytest.raises(InputError):
            MemberId.from_name(bad)
    with pytest.raises(InputError, match="takes no work"):
        keys.work_key_of("master/m/0")
