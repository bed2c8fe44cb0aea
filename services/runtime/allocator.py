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

glibc also trims the top of its heap by itself once the free space there exceeds twice its mmap threshold
(about 25 MB for a 1080p share). A frame's arrays freed at the top then go back to the system and the next
frame faults them in again: a master sharing a 1080p frame with a member host took 1,390 minor page faults a
frame (5.7 MB) against 150 computing alone, and its own patches cost 0.19-0.22 ms of its thread's CPU against
0.15. :data:`HeapPolicy.WARM`, the services' policy, leaves the trimming to :class:`HeapTrim` alone: the
mmap threshold is fixed at glibc's own ceiling of it (32 MB, where it would raise itself to) and the top is
never trimmed by glibc (``capataz bench dispatch --heap-policies warm glibc`` measures both in one run).

A thread's own arena (glibc gives each thread one, up to 8 a core) is a chain of 64 MB heaps, and one whose
blocks are all freed is unmapped whatever the thresholds: the master's frames thread still faulted 1,175
pages a frame in with the thresholds alone, 51 with one arena (``MALLOC_ARENA_MAX=1``). glibc reads that
limit once, before a second thread allocates, so it comes from the environment the process starts with:
:func:`process_environment` is what ``capataz up``, the load test and the benches start every process with,
and the image sets it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import enum
import logging
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from common.errors import CapatazError

logger = logging.getLogger(__name__)

MB = 2**20
#: glibc's ``mallopt`` parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: blocks below it come from the heap: glibc's ceiling of its self-raising threshold on 64-bit systems
WARM_MMAP_THRESHOLD_BYTES = 32 * MB
#: the largest value ``mallopt`` takes (an ``int``): glibc never trims the heap's top by itself
WARM_TRIM_THRESHOLD_BYTES = 2**31 - 1
#: the environment variable a service reads its heap policy from (a bench compares policies through it)
HEAP_POLICY_ENV = "CAPATAZ_HEAP"


class AllocatorError(CapatazError):
    """A heap policy that is not one."""


class HeapPolicy(enum.StrEnum):
    """How a compute service's C allocator keeps the pages its arrays free (see the module docstring)."""

    #: freed heap pages stay resident until :class:`HeapTrim` hands them back (the services' default)
    WARM = "warm"
    #: glibc as it comes: it also trims the heap's top by itself
    GLIBC = "glibc"


def heap_policy_from(environ: Mapping[str, str]) -> HeapPolicy:
    """The policy :data:`HEAP_POLICY_ENV` names in ``environ`` (unset or empty: :data:`HeapPolicy.WARM`)."""
    value = environ.get(HEAP_POLICY_ENV, "") or HeapPolicy.WARM.value
    try:
        return HeapPolicy(value)
    except ValueError:
        choices = ", ".join(p.value for p in HeapPolicy)
        raise AllocatorError(f"{HEAP_POLICY_ENV}={value!r} is not a heap policy: one of {choices}") from None


#: glibc's environment variable of the arena limit (read once, at the process's start)
ARENA_ENV = "MALLOC_ARENA_MAX"


def process_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """What a compute process must start with for the heap policy ``environ`` names: one malloc arena for
    :data:`HeapPolicy.WARM` (unless ``environ`` sets the limit itself), nothing for glibc's own policy."""
    if heap_policy_from(environ) is not HeapPolicy.WARM or ARENA_ENV in environ:
        return {}
    return {ARENA_ENV: "1"}


@contextmanager
def children_heap_policy(policy: HeapPolicy) -> Iterator[None]:
    """Processes started inside run under ``policy`` (:data:`HEAP_POLICY_ENV`, which they inherit); this
    process's own allocator is left as it is."""
    before = os.environ.get(HEAP_POLICY_ENV)
    os.environ[HEAP_POLICY_ENV] = policy.value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(HEAP_POLICY_ENV, None)
        else:
            os.environ[HEAP_POLICY_ENV] = before


def _libc_function(name: str) -> Any | None:
    """The C library's function ``name`` (ctypes), or None where it has none (not glibc)."""
    try:
        return getattr(ctypes.CDLL(ctypes.util.find_library("c")), name)
    except (OSError, AttributeError, TypeError):
        return None


def mallopt(param: int, value: int) -> bool:
    """glibc's ``mallopt(param, value)`` (process-wide); False where the C library has none or refused it."""
    function = _libc_function("mallopt")
    if function is None:
        return False
    function.argtypes, function.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(function(param, value))


def apply_heap_policy(policy: HeapPolicy) -> bool:
    """Set this process's C allocator to ``policy`` (process-wide: a service does it once, at its start);
    True when the C library took it (glibc), False where there is nothing to set."""
    if policy is HeapPolicy.GLIBC:
        return True
    if _libc_function("mallopt") is None:
        logger.info("heap policy %s: no glibc mallopt, the C library's own policy stays", policy.value)
        return False
    # the threshold first: setting either fixes both (glibc stops raising the threshold itself)
    return mallopt(M_MMAP_THRESHOLD, WARM_MMAP_THRESHOLD_BYTES) and mallopt(
        M_TRIM_THRESHOLD, WARM_TRIM_THRESHOLD_BYTES
    )


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
    trim = _libc_function("malloc_trim")
    if trim is None:
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

    @classmethod
    def for_service(cls, mark_mb: float, environ: Mapping[str, str] = os.environ) -> HeapTrim:
        """A compute service's trim, its process set to the heap policy ``environ`` names (default
        :data:`HeapPolicy.WARM`), which it logs."""
        policy = heap_policy_from(environ)
        applied = apply_heap_policy(policy)
        logger.info(
            "heap policy %s%s, trim past %.0f MB", policy.value, "" if applied else " (not set)", mark_mb
        )
        if process_environment(environ):  # started without the arena limit its policy wants
            logger.info(
                "%s is not set: each thread's arena hands its pages back when emptied (start with %s=1, as "
                "capataz up and the image do)", ARENA_ENV, ARENA_ENV,
            )  # fmt: skip
        return cls(mark_mb)

    def after_job(self) -> bool:
        """Trim when resident memory exceeds the mark; True when it did."""
        if self._trim is None or self._read_resident() <= self.mark_bytes:
            return False
        self._trim()
        self.trims += 1
        return True
