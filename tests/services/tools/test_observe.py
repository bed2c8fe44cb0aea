"""The cluster observers' pure parts: a member's refused inputs and dropped frames, one sum each, read the
same way by ``status``, ``metrics`` and ``up``'s summary; and who is alive, one watch for ``up``, ``status``
and the network harness's agent."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.wire import keys
from common.wire.messages import Stats, YawEstimate
from services.runtime.transport import open_session
from services.tools.observe import (
    DROPPED_COUNTERS,
    REFUSED_COUNTERS,
    AliveWatch,
    dropped_count,
    median_timings_ms,
    member_rows,
    refused_count,
)
from tests.zenoh_helpers import hub, peer, wait_until

#: the input gate's refusal counters (``refused_<sensor>_<reason>``) and counters of no refusal or drop
GATE = {"refused_imu_stale", "refused_camera_foreign"}
OTHER = {"frames_in", "queries", "yaw_out"}
names = st.sampled_from(sorted(REFUSED_COUNTERS | DROPPED_COUNTERS | GATE | OTHER))


@given(st.dictionaries(names, st.integers(0, 10**6)))
def test_refused_and_dropped_add_up_their_own_counters_only(counters: dict[str, int]) -> None:
    other = sum(v for k, v in counters.items() if k in OTHER)
    assert refused_count(counters) + dropped_count(counters) + other == sum(counters.values())
    assert refused_count({**counters, "frames_in": 7}) == refused_count(counters)
    assert dropped_count({**counters, "dropped_frames": counters.get("dropped_frames", 0) + 2}) == (
        dropped_count(counters) + 2
    )


def test_up_summary_rows_count_like_status() -> None:
    counters = {"frames_in": 5, "frames_dropped": 2, "queue_full": 3, "malformed": 1, "refused_imu_stale": 2}
    stats = Stats(role="worker", node="h1", index=0, uptime_s=1.0, stamp_s=0.0, counters=counters)
    (row,) = member_rows(["worker/h1/0"], {}, {"worker/h1/0": stats}, {})
    assert (row["inputs"], row["dropped"], row["refused"]) == (5, 2, 6)


class _GaveUpError(Exception):
    pass


@pytest.mark.zenoh
def test_alive_watch_follows_the_members_tokens_and_passes_over_foreign_ones() -> None:
    with hub() as endpoint, open_session(peer(endpoint)) as members, open_session(peer(endpoint)) as ours:
        worker = members.liveliness().declare_token(keys.alive_key("worker", "h1", 0))
        foreign = members.liveliness().declare_token(f"{keys.ROOT}/alive/not-a-member")
        watch = AliveWatch(ours)
        try:
            assert watch.wait_for({"worker/h1/0"}, 10.0)  # a token declared before the watch: its history
            camera = members.liveliness().declare_token(keys.alive_key("camera", "c", 0))
            assert watch.wait_for({"worker/h1/0", "camera/c/0"}, 10.0)
            assert watch.names() == {"worker/h1/0", "camera/c/0"}
            assert set(watch.first_seen_s) == {"worker/h1/0", "camera/c/0"}
            first_s = watch.first_seen_s["camera/c/0"]
            camera.undeclare()
            assert wait_until(lambda: watch.names() == {"worker/h1/0"})
            assert watch.first_seen_s["camera/c/0"] == first_s  # still when it was first seen
            assert not watch.wait_for({"master/m/0"}, 0.3)

            def give_up() -> None:
                raise _GaveUpError

            with pytest.raises(_GaveUpError):
                watch.wait_for({"master/m/0"}, 10.0, give_up)
            assert watch.wait_for({"worker/h1/0"}, 10.0, give_up)  # no check once all are alive
        finally:
            watch.close()
            worker.undeclare()
            foreign.undeclare()


def test_the_master_s_stage_timings_are_the_median_over_the_estimates() -> None:
    def estimate(seq: int, total_ms: float, round_ms: float | None) -> YawEstimate:
        timings = {"total": total_ms} if round_ms is None else {"total": total_ms, "round": round_ms}
        return YawEstimate(uav="uav0", seq=seq, stamp_s=seq / 20, delta_yaw_rad=0.0, yaw_rad=0.0,
                           inlier_count=0, patch_count=0, confidence=0.0, low_confidence=True,
                           method="initial", timings_ms=timings)  # fmt: skip

    estimates = [estimate(0, 30.0, 10.0), estimate(1, 90.0, None), estimate(2, 50.0, 20.0)]
    assert median_timings_ms(estimates) == {"round": 15.0, "total": 50.0}
    assert median_timings_ms([]) == {}
