"""The time-ordered buffer: out-of-order input comes out in stamp order after the lag; stale and
duplicate samples are refused; the buffer is bounded."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.errors import InputError
from common.estimation.buffer import Refusal, TimeOrderedBuffer


@given(st.lists(st.floats(0.0, 0.02), min_size=1, max_size=50), st.randoms())
def test_jittered_input_is_released_in_stamp_order(jitters: list[float], rnd) -> None:
    buffer: TimeOrderedBuffer[int] = TimeOrderedBuffer(max_lag_s=0.03)
    stamps = [0.01 * i for i in range(len(jitters))]
    arrival = sorted(range(len(stamps)), key=lambda i: stamps[i] + jitters[i])
    released = []
    for i in arrival:
        assert buffer.push(stamps[i], "imu", i) is None
        released.extend(buffer.pop_due())
    released.extend(buffer.drain())
    assert [t.item for t in released] == list(range(len(stamps)))
    assert len(buffer) == 0


def test_stale_duplicate_and_overflow_are_refused() -> None:
    buffer: TimeOrderedBuffer[str] = TimeOrderedBuffer(max_lag_s=0.0, max_items=2)
    assert buffer.push(1.0, "imu", "a") is None
    assert buffer.push(1.0, "imu", "again") is Refusal.DUPLICATE
    assert buffer.push(1.0, "range", "same stamp, other sensor") is None
    assert buffer.push(1.5, "imu", "full") is Refusal.OVERFLOW
    assert [t.item for t in buffer.pop_due()] == ["a", "same stamp, other sensor"]
    assert buffer.push(0.5, "imu", "late") is Refusal.STALE
    assert buffer.push(1.0, "imu", "released duplicate") is Refusal.DUPLICATE
    assert buffer.push(2.0, "imu", "b") is None
    assert buffer.released_until_s == 1.0


def test_equal_stamps_are_released_by_rank() -> None:
    buffer: TimeOrderedBuffer[str] = TimeOrderedBuffer(max_lag_s=0.0)
    buffer.push(1.0, "camera", "c", rank=3)
    buffer.push(1.0, "imu", "i", rank=1)
    buffer.push(1.0, "range", "r", rank=0)
    assert [t.item for t in buffer.drain()] == ["r", "i", "c"]


def test_lag_holds_samples_back() -> None:
    buffer: TimeOrderedBuffer[int] = TimeOrderedBuffer(max_lag_s=0.05)
    buffer.push(0.00, "imu", 0)
    buffer.push(0.03, "imu", 1)
    assert buffer.pop_due() == []
    buffer.push(0.06, "imu", 2)
    assert [t.item for t in buffer.pop_due()] == [0]


def test_the_first_pending_sample_of_a_sensor_is_seen_and_left_in_place() -> None:
    buffer: TimeOrderedBuffer[str] = TimeOrderedBuffer(max_lag_s=0.05)
    assert buffer.first_pending("imu") is None
    for stamp_s, sensor, item in ((0.03, "imu", "i3"), (0.01, "range", "r1"), (0.02, "imu", "i2")):
        buffer.push(stamp_s, sensor, item)
    assert buffer.first_pending("imu") == "i2"
    assert buffer.first_pending("camera") is None
    assert len(buffer) == 3
    assert [t.item for t in buffer.drain()] == ["r1", "i2", "i3"]


def test_invalid_arguments() -> None:
    with pytest.raises(InputError):
        TimeOrderedBuffer(max_lag_s=-1.0)
    with pytest.raises(InputError):
        TimeOrderedBuffer(max_items=0)
    with pytest.raises(InputError):
        TimeOrderedBuffer[int]().push(math.nan, "imu", 0)
