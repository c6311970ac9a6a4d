"""Keep freed memory in the process: large batched steps then reuse it instead of page-faulting.

glibc returns every block above its mmap threshold (at most 32 MB) to the system when it is freed,
so each new intermediate tensor of a large batch costs first-touch page faults, often more than
the arithmetic on it (a 7 MB tensor: about 2 ms of faults). `keep_freed_memory()` raises the
threshold to its maximum and stops trimming, as tcmalloc or jemalloc would. It changes how the
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
    ok &= libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)
    ok &= libc.mallopt(_M_TOP_PAD, 64 * 1024 * 1024)
    _done = bool(ok)
    return _done
