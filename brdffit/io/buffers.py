"""Host arrays that JAX can use in place.

JAX on the CPU uses a numpy array as a device buffer without copying it when its
data start on a 64-byte boundary; numpy's large allocations start 16 bytes past
one. A table (35 MB) or a weight map (12 MB) allocated here reaches every compiled
pass of a fit without a copy per table.
"""

from __future__ import annotations

import numpy as np

#: The alignment XLA's CPU client needs to use a host buffer in place.
DEVICE_ALIGNMENT = 64


def aligned_empty(n: int, dtype) -> np.ndarray:
    """An uninitialised 1-D array of ``n`` elements of ``dtype``, 64-byte aligned."""
    dtype = np.dtype(dtype)
    size = n * dtype.itemsize
    buffer = np.empty(size + DEVICE_ALIGNMENT, dtype=np.uint8)
    offset = -buffer.ctypes.data % DEVICE_ALIGNMENT
    return buffer[offset:offset + size].view(dtype)


def aligned_copy(a: np.ndarray) -> np.ndarray:
    """``a`` (any shape) copied into a 64-byte-aligned array of the same dtype."""
    out = aligned_empty(a.size, a.dtype).reshape(a.shape)
    out[...] = a
    return out
