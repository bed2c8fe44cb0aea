"""The spectrum cache is bounded in bytes across all its streams, not per stream name (issue 27 section 3: a
job within every wire bound made a worker keep about 75 MB per stream name, 64 names about 4.8 GB)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from common.yaw.correlation import PatchSpectra
from common.yaw.patchwork import SpectrumCache

MB = 2**20


def _share(n_patches: int, side: int) -> PatchSpectra:
    """A share's spectra (``np.empty`` commits no memory until written: the largest jobs cost nothing)."""
    return PatchSpectra(
        indices=np.arange(n_patches, dtype=np.intp),
        spectra=np.empty((n_patches, side, side), np.complex64),
        texture_std=np.zeros(n_patches, np.float32),
    )


def test_2400_stream_names_of_the_largest_job_stay_within_the_budget() -> None:
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


@given(
    st.lists(
        st.tuples(st.integers(0, 9), st.integers(0, 5), st.integers(1, 6), st.sampled_from([8, 16, 32])),
        min_size=1,
        max_size=60,
    ),
    st.integers(1, 6),
)
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
