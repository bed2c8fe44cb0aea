"""The C allocator of a process that holds large arrays for many streams: freed heap pages go back to the
system once the process holds more than a mark, and only then.

glibc serves a block above its mmap threshold (128 KB at start) with its own mapping, returned to the system
when freed; but each such free raises the threshold to the block's size (up to 32 MB), so later blocks of a
few MB (a job's crops, a stream's kept crops) are carved from the heap, whose freed space stays resident when
a block still in use lies above it. A foreman serving the largest blocks under 40 stream names so peaked at
721 MB where what it held came to about 470 MB (tests/integration/test_member_memory_budget.py).

Fixing the threshold at 1 MB bounded that, but every array of 1 MB or more then got a fresh mapping whose
pages the kernel faults in and zeroes on first touch: a worker measuring 30 patches of 128 px spent 0.78 ms
a patch where the same core spends 0.23 (``capataz bench allocator``; issue 29's two-host latency). Here
glibc keeps its own threshold, so a job's arrays reuse the pages the last job freed, and after a job
:class:`HeapTrim` hands the freed heap pages back (``malloc_trim(0)``: every arena, free pages anywhere in a
heap, not only at its top) when the process's resident memory exceeds its mark: a steady stream keeps its
warm pages, and a burst of large jobs under many stream names stays within the memory budget.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
from collections.abc import Callable

logger = logging.getLogger(__name__)

MB = 2**20


def resident_bytes() -> int:
    """This process's resident memory now (``/proc/self/statm``), or 0 where it cannot be read."""
    try:
        with open("/proc/self/statm", "rb") as statm:
            pages = int(statm.read().split()[1])
    except (OSError, ValueError, IndexError):
        return 0
    return pages * os.sysconf("SC_PAGE_SIZE")


def _malloc_trim() -> Callable[[], bool] | None:
    """glibc's ``malloc_trim(0)`` as a call, or None where the C library has none."""
    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c")).malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return lambda: bool(trim(0))


class HeapTrim:
    """After a job: return the freed heap pages to the system when resident memory exceeds ``mark_mb``.

    The mark is a member's budget less one largest job's working set, so the next job, which reuses the pages
    left resident before it grows, peaks within the budget. ``read_resident`` and ``trim`` are the process's
    own (:func:`resident_bytes`, glibc's ``malloc_trim``) unless given (tests). Where there is no
    ``malloc_trim`` (not glibc) nothing is trimmed and that is logged once.
    """

    def __init__(
        self,
        mark_mb: float,
        read_resident: Callable[[], int] = resident_bytes,
        trim: Callable[[], bool] | None = None,
    ) -> None:
        if not mark_mb > 0:
            raise ValueError(f"mark_mb must be > 0, got {mark_mb}")
        self.mark_bytes = int(mark_mb * MB)
        self._read_resident = read_resident
        self._trim = trim if trim is not None else _malloc_trim()
        self.trims = 0
        if self._trim is None:
            logger.info("freed heap pages stay resident (no glibc malloc_trim)")

    def after_job(self) -> bool:
        """Trim when resident memory exceeds the mark; True when it did."""
        if self._trim is None or self._read_resident() <= self.mark_bytes:
            return False
        self._trim()
        self.trims += 1
        return True
