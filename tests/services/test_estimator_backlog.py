"""The estimator's backlog: the frame queue skips frames evenly (never the newest, never a burst) and each
frame taken says how far apart its VO pair is; held samples come out in stamp order up to a frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from common.errors import InputError
from services.estimator.backlog import HeldSamples, SpacedFrameQueue
from services.estimator.settings import EstimatorSettings


@dataclass(frozen=True)
class _Frame:
    stamp_s: float


def _run(
    capacity: int, schedule: list[bool], max_pair_s: float = math.inf, max_backlog_s: float = 0.0
) -> tuple[list[tuple[int, int]], list[int], list[int], int]:
    """Offer frame i (stamp i / 20) at each False and take one at each True; returns the taken frames with
    their spacing, the skipped and the still queued frame numbers, and the most ever queued."""
    queue: SpacedFrameQueue[_Frame] = SpacedFrameQueue(capacity, max_pair_s, max_backlog_s)
    taken: list[tuple[int, int]] = []
    skipped: list[int] = []
    deepest = 0
    n = 0
    for take in schedule:
        if take:
            got = queue.take()
            if got is not None:
                taken.append((round(got[0].stamp_s * 20), got[1]))
            continue
        out = queue.offer(_Frame(n / 20))
        if out is not None:
            skipped.append(round(out.stamp_s * 20))
        deepest = max(deepest, queue.depth())
        n += 1
    rest = []
    while (got := queue.take()) is not None:
        rest.append(round(got[0].stamp_s * 20))
    return taken, skipped, rest, deepest


@given(st.integers(2, 10), st.lists(st.booleans(), max_size=300))
def test_every_frame_is_taken_skipped_or_queued_once_and_spacings_count_the_skipped(
    capacity: int, schedule: list[bool]
) -> None:
    taken, skipped, rest, deepest = _run(capacity, schedule)
    offered = schedule.count(False)
    used = [i for i, _ in taken]
    assert sorted(used + skipped + rest) == list(range(offered))
    assert used == sorted(used) and deepest <= capacity
    previous = -1
    for i, spacing in taken:  # a pair spans the frames skipped since the previous frame taken
        assert spacing == i - previous if previous >= 0 else spacing >= 1
        previous = i
    if offered:
        assert offered - 1 not in skipped  # the newest frame is never the one skipped


@pytest.mark.parametrize("every", [1, 2, 3, 4, 5])
def test_a_filter_that_keeps_up_with_one_frame_in_k_pairs_frames_k_apart(every: int) -> None:
    """A steady backlog spaces the pairs evenly: the filter taking one frame in ``k`` pairs frames ``k``
    apart (the VO handles 2-3 as well as 1), never a burst of lost frames followed by a long gap."""
    schedule = []
    for i in range(400):
        schedule += [False, True] if i % every == 0 else [False]
    taken, skipped, _, _ = _run(6, schedule)
    spacings = [s for _, s in taken]
    assert len(skipped) > 0 if every > 1 else not skipped
    assert max(spacings[1:]) <= every + 1
    assert spacings[-50:] == [every] * 50


def test_a_short_stall_is_worked_off_frame_by_frame() -> None:
    taken, skipped, _, _ = _run(6, [False] * 6 + [True] * 6)
    assert not skipped and [s for _, s in taken] == [1] * 6


def test_a_stall_queues_frames_rather_than_pairing_frames_too_far_apart_until_the_backlog_bound() -> None:
    """Pairs up to 0.2 s (4 frames) apart: a 2 s stall of the filter is absorbed as latency (the queue
    grows, every pair stays within 4 frames); a stall longer than the 3 s backlog widens the pairs."""
    stall = [False] * 40 + [True] * 60  # 2 s of frames while the filter is stalled, then it catches up
    taken, skipped, _, deepest = _run(6, stall, max_pair_s=0.2, max_backlog_s=3.0)
    assert max(s for _, s in taken) <= 4 and 6 < deepest < 40 and len(taken) + len(skipped) == 40
    long_stall = [False] * 100 + [True] * 100  # 5 s
    taken, _, _, deepest = _run(6, long_stall, max_pair_s=0.2, max_backlog_s=3.0)
    assert max(s for _, s in taken) > 4 and deepest <= 25  # 3 s of frames at most 4 apart, not 100


def test_a_clock_that_goes_back_keeps_the_queue_bounded() -> None:
    queue: SpacedFrameQueue[_Frame] = SpacedFrameQueue(4, max_pair_s=0.2, max_backlog_s=3.0)
    for i in range(10):
        queue.offer(_Frame(100.0 + i / 20))
    assert queue.take() is not None
    for i in range(200):  # a restarted camera: stamps from 0 again, far behind the frame taken last
        queue.offer(_Frame(i / 20))
        assert queue.depth() <= 3.0 * 20 / 2  # 3 s of frames, as with a stream that never restarted
    assert queue.take() is not None


@pytest.mark.parametrize("capacity", [1, SpacedFrameQueue.HARD_CAPACITY + 1])
def test_a_queue_needs_room_for_two_frames_and_is_bounded(capacity: int) -> None:
    with pytest.raises(InputError, match="capacity of 2 to"):
        SpacedFrameQueue(capacity)


@given(
    st.lists(st.lists(st.integers(0, 1000), max_size=20), max_size=20),
    st.lists(st.integers(0, 1000), max_size=20),
    st.integers(1, 50),
)
def test_held_samples_come_out_in_stamp_order_up_to_the_frame_and_stay_bounded(
    batches: list[list[int]], frames: list[int], capacity: int
) -> None:
    held: HeldSamples[_Frame] = HeldSamples(capacity)
    released: list[float] = []
    for batch, frame in zip(batches, frames, strict=False):
        overflow = held.add([_Frame(float(t)) for t in batch])
        assert len(held) <= capacity
        released += [m.stamp_s for m in overflow]
        before = [m.stamp_s for m in held.until(float(frame))]
        assert before == sorted(before) and all(t <= frame for t in before)
        assert held.until(float(frame)) == []  # nothing up to the frame is left
        released += before
    released += [m.stamp_s for m in held.until(math.inf)]
    added = batches[: len(frames)]
    assert sorted(released) == sorted(float(t) for batch in added for t in batch)


@pytest.mark.parametrize(
    "field", [{"frame_queue": 1}, {"frame_queue": 129}, {"max_pair_s": 0.0}, {"max_backlog_s": 9.0}]
)
def test_backlog_settings_out_of_range_are_refused(field: dict[str, float]) -> None:
    with pytest.raises(ValidationError, match=next(iter(field))):
        EstimatorSettings(**field)  # type: ignore[arg-type]
