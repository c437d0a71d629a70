"""The bake's process gives freed buffers back to the system (`return_freed_buffers`).

glibc's malloc serves an allocation of at least its mmap threshold (128 KiB at first) with its
own mapping, unmapped when freed; but each such free raises the threshold to the freed size (up to
32 MiB), after which buffers of that size come from the heap, where a freed one stays resident
behind live ones. A bake frees many arrays of 1 to 32 MiB (per-node LODs, blocks, chunks): in a
2M-triangle bake the process kept about 100 bytes an input triangle resident that no live object
held. Fixing the threshold keeps every large buffer in a mapping of its own (mallopt(3),
M_MMAP_THRESHOLD). Other C libraries (macOS, Windows, musl) are left as they are.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

#: mallopt's parameter number for the mmap threshold (glibc's malloc.h).
M_MMAP_THRESHOLD = -3
#: Buffers of at least this many bytes get a mapping of their own, returned to the system when freed.
MMAP_THRESHOLD_BYTES = 256 * 1024


def return_freed_buffers(platform: str | None = None) -> bool:
    """Fix glibc's mmap threshold at MMAP_THRESHOLD_BYTES for this process (module docstring);
    whether it was set (False: not Linux, or not glibc). Process-wide: for the bake's own processes
    (the command line, the add-on's bake child), not for a host that imports the core."""
    if (sys.platform if platform is None else platform) != "linux":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl has no mallopt
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
