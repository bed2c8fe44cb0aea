"""The foreman's crop store is bounded in bytes across all its streams, not per stream name (issue 27 section
3: the foreman's CropStore kept two frames of crops per stream name without a byte bound)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.wire.schema import MAX_CROP_SIDE_PX, MAX_JOB_PIXELS
from common.yaw.patchwork import CropStore, PatchWorkError

MB = 2**20


def _largest_job() -> tuple[np.ndarray, np.ndarray]:
    """The largest crops a job may carry (``np.empty`` commits no memory until written)."""
    n = MAX_JOB_PIXELS // MAX_CROP_SIDE_PX**2
    return np.arange(n), np.empty((n, MAX_CROP_SIDE_PX, MAX_CROP_SIDE_PX), np.uint8)


def test_2400_stream_names_of_the_largest_job_stay_within_the_budget() -> None:
    budget = 256 * MB
    store = CropStore(max_bytes=budget)
    indices, crops = _largest_job()
    peak = 0
    for k in range(2400):
        store.add(f"stream{k}", 1, indices, crops)
        peak = max(peak, store.nbytes)
    assert peak <= budget and len(store) == budget // crops.nbytes
    assert store.evicted == 2400 - len(store)
    assert store.get("stream2399", 1, indices[:2], crops.shape[1:]).shape == (2, *crops.shape[1:])
    with pytest.raises(PatchWorkError, match="stream0"):  # the least recent went first
        store.get("stream0", 1, indices[:1], crops.shape[1:])


def test_a_view_of_a_larger_buffer_is_copied_so_it_cannot_hold_the_buffer() -> None:
    payload = np.zeros(10 * MB, np.uint8)
    view = payload[: 4 * 16 * 16].reshape(4, 16, 16)
    store = CropStore(max_bytes=MB)
    store.add("s", 0, np.arange(4), view)
    assert store.nbytes == view.nbytes
    payload[:] = 9  # the store holds its own copy
    assert store.get("s", 0, np.array([3]), (16, 16))[0, 0, 0] == 0


@given(
    st.lists(
        st.tuples(st.integers(0, 6), st.integers(0, 8), st.integers(1, 5), st.sampled_from([4, 8, 16])),
        min_size=1,
        max_size=50,
    ),
    st.integers(1, 8),
)
def test_the_store_accounts_every_byte_it_holds_and_stays_within_budget(
    adds: list[tuple[int, int, int, int]], budget_crops: int
) -> None:
    budget = budget_crops * 16 * 16 * 5
    store = CropStore(max_bytes=budget)
    for stream, seq, n, side in adds:
        crops = np.full((n, side, side), seq, np.uint8)
        store.add(f"s{stream}", seq, np.arange(n), crops)
        held = sum(a.nbytes for frames in store._streams.values() for f in frames.values() for a in f.arrays)
        assert held == store.nbytes
        assert store.nbytes <= budget or len(store) == 1  # only the stream just stored may exceed it
        assert all(len(frames) <= 2 for frames in store._streams.values())
