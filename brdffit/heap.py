"""How a long-lived fitting process uses the C heap: keep freed memory while it works,
give it back when it is idle.

A fit allocates and frees arrays of a whole table (1.46M bins x 3 channels: 17-35 MB)
many times: the full-table error pass, the sphere renders, the table's device copy.
glibc's malloc serves blocks that large with ``mmap`` and unmaps them on ``free``
(its threshold grows only to 32 MB), so every pass faults its pages in again, and the
kernel zeroes them: a batch worker spent ~40% of its time in the kernel (51 real
tables x 6 models on 2 workers: 47-59 s user, 23-30 s system). With the thresholds
raised (:func:`keep_freed_memory`) the blocks come from the heap and are reused.

The memory a process then holds after its peak is given back on request
(:func:`give_memory_back`, ``malloc_trim``): a service worker calls it after each job,
so that an idle worker does not sit on its last job's peak.

Both are glibc's (Linux); elsewhere they do nothing, and say so in their return value.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

#: mallopt parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: Blocks below this come from the heap, and freed memory above it at the heap's top
#: is kept: larger than any array a fit of a MERL table makes (~100 MB).
KEEP_BYTES = 1 << 30


@functools.cache
def _libc():
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
    except OSError:
        return None
    if libc is None or not hasattr(libc, "mallopt") or not hasattr(libc, "malloc_trim"):
        return None  # not glibc (musl, macOS): its own policy stands
    return libc


@functools.cache
def keep_freed_memory() -> bool:
    """Serve large blocks from the heap and keep what is freed, in this process; True
    where that took effect (glibc). Once per process: later calls return the first's
    answer."""
    libc = _libc()
    if libc is None:
        return False
    return bool(libc.mallopt(_M_MMAP_THRESHOLD, KEEP_BYTES)
                and libc.mallopt(_M_TRIM_THRESHOLD, KEEP_BYTES))


def give_memory_back() -> bool:
    """Return the heap's free memory to the system (``malloc_trim(0)``); True where
    some was returned."""
    libc = _libc()
    return bool(libc is not None and libc.malloc_trim(0))
