"""The C allocator of a process that holds large arrays for many streams: freed blocks go back to the system.

glibc serves a block above its mmap threshold (128 KB at start) with its own mapping, returned to the system
when freed; but each such free raises the threshold to the block's size (up to 32 MB), so later blocks of a
few MB (a job's crops, a stream's kept crops) are carved from the heap, whose freed space stays resident when
a block still in use lies above it. A foreman serving the largest blocks under 40 stream names so peaked at
721 MB where what it held came to about 470 MB (tests/integration/test_member_memory_budget.py); with the
threshold fixed at 1 MB it peaked at 522 MB. Blocks below it (every array of the default 32 px patches) are
served as before.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

logger = logging.getLogger(__name__)

#: glibc's ``mallopt`` parameter of the mmap threshold (malloc.h); setting it also stops its dynamic raising
M_MMAP_THRESHOLD = -3
#: blocks this large or larger get a mapping of their own, returned to the system when freed
MMAP_THRESHOLD_BYTES = 1 << 20


def return_large_blocks(threshold_bytes: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix the C allocator's mmap threshold at ``threshold_bytes``; False where the C library is not glibc."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        done = bool(libc.mallopt(M_MMAP_THRESHOLD, threshold_bytes))
    except (OSError, AttributeError, TypeError):
        done = False
    if not done:
        logger.info("the C library's mmap threshold stays as it is (no glibc mallopt)")
    return done
