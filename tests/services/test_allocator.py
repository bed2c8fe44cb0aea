"""The members' allocator policy: freed heap pages go back only past a mark, so jobs reuse warm pages."""

from __future__ import annotations

import argparse
import subprocess
import sys
import textwrap

import pytest

from services.runtime import allocator
from services.runtime.allocator import HeapTrim, resident_bytes
from services.tools.bench.allocator import run_policy

MB = 2**20


def test_trims_only_when_resident_memory_exceeds_the_mark() -> None:
    resident = [100 * MB]
    calls: list[int] = []
    heap = HeapTrim(200.0, read_resident=lambda: resident[0], trim=lambda: bool(calls.append(1)) or True)
    assert not heap.after_job() and not calls
    resident[0] = 200 * MB  # at the mark: nothing to hand back yet
    assert not heap.after_job() and not calls
    resident[0] = 200 * MB + 1
    assert heap.after_job() and calls == [1] and heap.trims == 1


def test_without_malloc_trim_nothing_is_trimmed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(allocator, "_malloc_trim", lambda: None)  # a C library without malloc_trim
    heap = HeapTrim(1e-6, read_resident=lambda: 10**12)
    assert not heap.after_job() and heap.trims == 0


@pytest.mark.parametrize("mark_mb", [0.0, -1.0, float("nan")])
def test_a_mark_must_be_positive(mark_mb: float) -> None:
    with pytest.raises(ValueError, match="mark_mb"):
        HeapTrim(mark_mb)


def test_resident_memory_is_read_from_proc() -> None:
    assert resident_bytes() > 10 * MB  # an interpreter with numpy


def test_a_trim_hands_freed_heap_pages_back() -> None:
    """Blocks of 4 MB carved from the heap (glibc's threshold raised by the first free), all freed but the
    last: resident until trimmed, and a trim past the mark hands them back."""
    code = textwrap.dedent(
        """
        import numpy as np
        from services.runtime.allocator import HeapTrim, resident_bytes
        first = np.ones(8 << 20, np.uint8); del first  # raises the mmap threshold to 8 MB
        blocks = [np.ones(4 << 20, np.uint8) for _ in range(60)]
        last = blocks.pop(); del blocks
        before = resident_bytes()
        trimmed = HeapTrim(1e-6).after_job()
        print(trimmed, before, resident_bytes(), last.sum() > 0)
        """
    )
    command = [sys.executable, "-c", code]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=True)
    trimmed, before, after, _ = done.stdout.split()
    if trimmed != "True":
        pytest.skip("no glibc malloc_trim here")
    assert int(before) - int(after) > 150 * MB, (before, after)


def test_a_workers_jobs_reuse_warm_pages_instead_of_fresh_mappings_regression() -> None:
    """Regression: the members fixed glibc's mmap threshold at 1 MB, so every array of a job of 30 patches of
    128 px was a fresh mapping, faulted in and zeroed (about 8,000 page faults a job, 3.5 times the compute,
    ``capataz bench allocator``). The services' policy faults in (almost) nothing once warm."""
    args = argparse.Namespace(jobs=6, patches=30, resolution="752x480", patch_size=128)
    services = run_policy("heap_trim", args)
    before = run_policy("mmap_1mb", args)
    assert max(services["faults_per_job"]) < 200, services["faults_per_job"]
    assert min(before["faults_per_job"]) > 2000, before["faults_per_job"]
