"""Keep freed memory in the process: large batched steps then reuse it instead of page-faulting.

glibc maps every block above its mmap threshold (at most 32 MB) afresh and unmaps it when freed,
so each new intermediate tensor of a large batch costs first-touch page faults, often more than
the arithmetic on it (experiments/speed_history.md). `keep_freed_memory()` serves every
block from the heap and stops trimming it, as tcmalloc or jemalloc would: freed memory is reused
and not returned to the system while the process lives. It changes how the
process allocates, not what it computes; torchik's command line and benchmarks call it, and a
library user can.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4
_done = False


def keep_freed_memory() -> bool:
    """Tune glibc malloc to keep freed blocks for reuse. Returns False where it does not apply."""
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    libc = ctypes.CDLL(name)
    if not hasattr(libc, "mallopt"):  # musl and other C libraries
        return False
    ok = libc.mallopt(_M_MMAP_THRESHOLD, 32 * 1024 * 1024)
    # blocks above the threshold's ceiling (32 MB, e.g. a batch's Hessians) would still be mapped
    # afresh every time: serve every block from the heap instead
    ok &= libc.mallopt(_M_MMAP_MAX, 0)
    ok &= libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    ok &= libc.mallopt(_M_TOP_PAD, 64 * 1024 * 1024)
    _done = bool(ok)
    return _done
