"""The cluster observers' pure parts: a member's refused inputs and dropped frames, one sum each, read the
same way by ``status``, ``metrics`` and ``up``'s summary."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from common.wire.messages import Stats
from services.tools.observe import (
    DROPPED_COUNTERS,
    REFUSED_COUNTERS,
    dropped_count,
    member_rows,
    refused_count,
)

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
