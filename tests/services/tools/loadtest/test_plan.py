"""The load test's pure parts: schedules, objectives, latency statistics, fault analysis, capacity search."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.dispatch import SELF
from services.tools.loadtest.plan import (
    Fault,
    FaultAction,
    FrameRecord,
    LoadtestError,
    Metric,
    analyse_fault,
    capacity_of,
    compute_share,
    evaluate,
    latency_stats,
    metric_values,
    next_capacity,
    parse_fault,
    parse_objective,
    parse_schedule,
    summarise,
)


def test_the_issue_schedule_parses_in_time_order() -> None:
    faults = parse_schedule(
        ["kill:master@50s,kill:worker@20s", "stop:foreman@30s+6s kill:router@40s # comment"]
    )
    assert [f.label for f in faults] == [
        "kill:worker@20s", "stop:foreman@30s+6s", "kill:router@40s", "kill:master@50s",
    ]  # fmt: skip
    assert faults[1] == Fault(FaultAction.STOP, "foreman", 30.0, 6.0)
    assert parse_fault("hostile:seq@10s").action is FaultAction.HOSTILE


@pytest.mark.parametrize(
    "text",
    ["kill:camera@1s", "kill:worker", "stop:worker@3s", "kill:worker@3s+2s", "hostile:nonsense@1s", "x", ""],
)
def test_bad_faults_are_refused_with_one_clear_error(text: str) -> None:
    with pytest.raises(LoadtestError, match="fault"):
        parse_fault(text)


def test_objectives_parse_and_judge() -> None:
    p99 = parse_objective("p99_ms<=50")
    assert p99.metric is Metric.P99_MS and p99.met(50.0) and not p99.met(50.1) and not p99.met(math.nan)
    lost = parse_objective("lost_pct<0.1")
    assert lost.met(0.05) and not lost.met(0.1)
    for bad in ("p99<=50", "p99_ms>=50", "p99_ms<=inf", "lost_pct"):
        with pytest.raises(LoadtestError):
            parse_objective(bad)


@given(st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=1, max_size=200))
def test_latency_percentiles_are_ordered_and_bounded(values: list[float]) -> None:
    stats = latency_stats(values)
    assert min(values) <= stats.p50 <= stats.p95 <= stats.p99 <= stats.max == max(values)
    assert stats.count == len(values)


def test_latency_of_nothing_is_nan_and_fails_every_latency_objective() -> None:
    stats = latency_stats([])
    assert math.isnan(stats.p99)
    assert not parse_objective("p99_ms<=1000").met(stats.p99)


def _stream(
    n: int = 200,
    fps: float = 20.0,
    lost: frozenset[int] | set[int] = frozenset(),
    jump_at: int | None = None,
    latency_s: float = 0.02,
) -> list[FrameRecord]:
    true = np.radians(10.0) * np.sin(np.arange(n) / 30.0)
    records = []
    for k in range(n):
        sent = 100.0 + k / fps
        if k in lost:
            records.append(FrameRecord(k, sent, None, None, float(true[k])))
            continue
        yaw = float(true[k]) + (np.radians(30.0) if jump_at is not None and k >= jump_at else 0.0)
        records.append(FrameRecord(k, sent, sent + latency_s, yaw, float(true[k])))
    return records


def test_a_fault_that_loses_one_frame_is_measured_as_such() -> None:
    records = _stream(lost={101})  # the fault at 5 s = frame 100
    outcome = analyse_fault(records, parse_fault("kill:worker@5s"), 100.0, 100.0 + 8.0)
    assert outcome.lost == 1
    assert outcome.gap_s == pytest.approx(0.1)
    assert outcome.recovery_s == pytest.approx(0.05)  # the lost frame, sent 50 ms after the fault
    assert outcome.yaw_discontinuity_deg == pytest.approx(0.0, abs=1e-9)


def test_a_yaw_reset_at_a_failover_is_a_discontinuity_and_breaks_the_objective() -> None:
    records = _stream(jump_at=120)
    outcome = analyse_fault(records, parse_fault("kill:master@5s"), 100.0, 110.0)
    assert outcome.yaw_discontinuity_deg == pytest.approx(30.0)
    values = metric_values([summarise("uav0", records, 0, 1.0)], [[outcome]])
    (verdict,) = evaluate([parse_objective("yaw_jump_deg<=1")], values)
    assert not verdict.met and verdict.value == pytest.approx(30.0)


def test_a_stop_recovers_after_its_duration() -> None:
    lost = set(range(100, 220))  # 6 s at 20 fps lost: the worker was stopped and nobody took over
    records = _stream(n=300, lost=lost)
    outcome = analyse_fault(records, parse_fault("stop:worker@5s+6s"), 100.0, 115.0)
    assert outcome.lost == 120 and outcome.recovery_s == pytest.approx(5.95)
    assert outcome.gap_s == pytest.approx(6.05)


def test_summary_counts_and_latency_exclude_the_warm_up() -> None:
    records = _stream(lost={3, 50}, latency_s=0.03)
    summary = summarise("uav0", records, reported_dropped=1, settle_s=1.0)
    assert (summary.published, summary.received, summary.lost) == (200, 198, 2)
    assert summary.latency.p99 == pytest.approx(30.0)
    values = metric_values([summary], [])
    assert values[Metric.LOST_PCT] == pytest.approx(1.0)


@given(st.integers(1, 40), st.integers(1, 64))
def test_capacity_search_finds_the_largest_passing_count(capacity: int, limit: int) -> None:
    tried: dict[int, bool] = {}
    for _ in range(30):
        n = next_capacity(tried, limit)
        if n is None:
            break
        tried[n] = n <= capacity
    else:
        raise AssertionError(f"search did not end: {tried}")
    assert capacity_of(tried) == min(capacity, limit)


def test_without_a_truth_yaw_continuity_is_not_judged() -> None:
    """A replayed recording has no true yaw: the yaw jump is NaN (unknown), never a reassuring 0, and an
    objective on it is not met."""
    records = [FrameRecord(r.seq, r.sent_s, r.received_s, r.yaw_rad, math.nan) for r in _stream(jump_at=120)]
    summary = summarise("uav0", records, 0, 0.0)
    assert math.isnan(summary.max_yaw_jump_deg) and summary.received == 200
    outcome = analyse_fault(records, parse_fault("kill:master@5s"), 100.0, 110.0)
    assert math.isnan(outcome.yaw_discontinuity_deg)
    values = metric_values([summary], [[outcome]])
    assert math.isnan(values[Metric.YAW_JUMP_DEG])
    (verdict,) = evaluate([parse_objective("yaw_jump_deg<=1")], values)
    assert not verdict.met


@given(st.lists(st.tuples(st.integers(0, 40), st.integers(0, 40)), max_size=50))
def test_the_cluster_share_counts_patches_and_frames_the_master_did_alone(
    frames: list[tuple[int, int]],
) -> None:
    computed = [(min(own, total), total) for own, total in frames]
    # the master's own patches and the rest split between two foremen
    halves = [((total - own) // 2, total - own - (total - own) // 2) for own, total in computed]
    members = [
        {SELF: own, "foreman/h1/0": h1, "foreman/h2/0": h2}
        for (own, _), (h1, h2) in zip(computed, halves, strict=True)
    ]
    share = compute_share(members)
    measured = [(own, total) for own, total in computed if total > 0]  # an epoch's first frame has none
    assert share.frames == len(measured)
    assert share.frames_alone == sum(1 for own, total in measured if own == total)
    assert 0.0 <= share.cluster_share <= 1.0
    if measured:
        own = sum(o for o, _ in measured)
        total = sum(t for _, t in measured)
        assert share.cluster_share == pytest.approx(1 - own / total)
        assert sum(share.by_member.values()) == pytest.approx(1.0)
        assert share.by_member[SELF] == pytest.approx(own / total)
        foremen = share.by_member["foreman/h1/0"] + share.by_member["foreman/h2/0"]
        assert foremen == pytest.approx(share.cluster_share)
    else:
        assert share.by_member == {}
