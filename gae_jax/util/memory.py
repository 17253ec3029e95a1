"""`keep_freed_memory`: the host allocator keeps large freed blocks for reuse.

XLA:CPU allocates a program's temporaries on every call. glibc serves a block larger than its
mmap threshold (at most 32 MB by default) with a fresh mapping and unmaps it on free, so a jitted
step whose temporaries exceed it page-faults all of them in again on every call: the fit step
that also renders a view no camera took (about 37 MB of temporaries at 128 px) took 9,460 page
faults and 24 ms of system time a step (46 ms a step against 34 with this setting). Raising
the mmap and trim thresholds keeps such blocks on the heap between calls. A process-wide
setting, so only entry points call it (`cli.prepare_process`); the same code runs unchanged
where the C library is not glibc (nothing is set) and on accelerators (their device memory has
its own allocator).
"""

from __future__ import annotations

import ctypes

# mallopt parameters (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
# Blocks up to this size come from the heap and stay there when freed.
KEEP_BYTES = 1 << 30


def keep_freed_memory(limit: int = KEEP_BYTES) -> bool:
    """Serve blocks up to `limit` bytes from the heap and return freed memory to the OS only
    beyond `limit` of free space at its top. Returns whether the C library took both settings
    (False where it has no `mallopt`)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(M_MMAP_THRESHOLD, limit)) and bool(mallopt(M_TRIM_THRESHOLD, limit))
