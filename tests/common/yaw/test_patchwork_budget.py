"""A member's spectrum cache and a foreman's crop store are bounded in bytes across all their streams, not per
stream name (issue 27 section 3: a job within every wire bound made a worker keep about 75 MB per stream name,
64 names about 4.8 GB; the foreman's CropStore kept two frames of crops per stream name without a byte
bound)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from common.wire.schema import MAX_CROP_SIDE_PX, MAX_JOB_PIXELS
from common.yaw.correlation import PatchSpectra
from common.yaw.patchwork import CropStore, PatchWorkError, SpectrumCache

MB = 2**20


def _stores(
    streams: int, seqs: int, patches: int, sides: list[int], max_size: int
) -> st.SearchStrategy[list[tuple[int, int, int, int]]]:
    """Stores across streams, each ``(stream, frame seq, patches, patch side)``."""
    cell = st.tuples(
        st.integers(0, streams), st.integers(0, seqs), st.integers(1, patches), st.sampled_from(sides)
    )
    return st.lists(cell, min_size=1, max_size=max_size)


def _share(n_patches: int, side: int) -> PatchSpectra:
    """A share's spectra (``np.empty`` commits no memory until written: the largest jobs cost nothing)."""
    return PatchSpectra(
        indices=np.arange(n_patches, dtype=np.intp),
        spectra=np.empty((n_patches, side, side), np.complex64),
        texture_std=np.zeros(n_patches, np.float32),
    )


def test_2400_stream_names_of_the_largest_share_stay_within_the_cache_budget() -> None:
    """The largest share the wire admits: 16 M pixels of crops, 256 px patches: 256 patches of 512 KB of
    spectra each (128 MB per stream name)."""
    budget = 512 * MB
    cache = SpectrumCache(max_streams=64, max_age_s=60.0, max_bytes=budget)
    largest = _share(256, 256)
    peak = 0
    for k in range(2400):
        cache.store(f"stream{k}", 1, largest)
        peak = max(peak, cache.nbytes)
    assert peak <= budget and len(cache) == budget // largest.spectra.nbytes
    assert cache.evicted == 2400 - len(cache)
    assert cache.held("stream2399")[0] == 1 and cache.held("stream0")[0] == -2  # the least recent went first


@given(_stores(9, 5, 6, [8, 16, 32], 60), st.integers(1, 6))
def test_the_cache_accounts_every_byte_it_holds_and_never_exceeds_its_budget(
    stores: list[tuple[int, int, int, int]], budget_patches: int
) -> None:
    budget = budget_patches * 32 * 32 * 8
    cache = SpectrumCache(max_streams=64, max_age_s=1e9, max_bytes=budget)
    for stream, seq, n, side in stores:
        cache.store(f"s{stream}", seq, _share(n, side))
        assert cache.nbytes <= budget
        held = sum(row[0].nbytes for entry in cache._streams.values() for row in entry.spectra.values())
        assert held == cache.nbytes


def test_without_a_budget_only_the_stream_count_bounds_it() -> None:
    cache = SpectrumCache(max_streams=3, max_age_s=60.0)
    for k in range(10):
        cache.store(f"s{k}", 0, _share(4, 16))
    assert len(cache) == 3 and cache.nbytes == 3 * 4 * 16 * 16 * 8


def _largest_job() -> tuple[np.ndarray, np.ndarray]:
    """The largest crops a job may carry (``np.empty`` commits no memory until written)."""
    n = MAX_JOB_PIXELS // MAX_CROP_SIDE_PX**2
    return np.arange(n), np.empty((n, MAX_CROP_SIDE_PX, MAX_CROP_SIDE_PX), np.uint8)


def test_2400_stream_names_of_the_largest_job_stay_within_the_store_budget() -> None:
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


@given(_stores(6, 8, 5, [4, 8, 16], 50), st.integers(1, 8))
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
