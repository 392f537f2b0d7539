"""Large per-frame arrays from the heap, not fresh pages: glibc's ``mallopt`` once per process.

An image-based reduction allocates the same few large arrays for every frame (~300 MB of
samples for a 24 MP frame). glibc serves allocations above its mmap threshold (32 MB at most
by default) with fresh anonymous pages, which the kernel zeroes on first touch and takes back
on free: a quarter of the per-pixel kernel's time went to zeroing pages. Raising the mmap and
trim thresholds keeps that memory in the process's heap, reused frame after frame: the whole
reduction of a 24 MP frame took 0.37 s instead of 0.44 s here. The process then keeps its peak
footprint until it exits (``bench/image_session.py`` holds the peak flat over 100 frames).
Other C libraries (musl, macOS) are left alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
HEAP_THRESHOLD_BYTES = 1 << 30
"""Allocations below this come from the heap, and up to twice it stays there once freed."""
_DONE: list[bool] = []


def keep_large_arrays_on_heap() -> bool:
    """Raise glibc's mmap and trim thresholds (once per process); True when they are set."""
    if _DONE:
        return _DONE[0]
    ok = False
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            ok = bool(libc.gnu_get_libc_version and libc.mallopt(_M_MMAP_THRESHOLD,
                                                                   HEAP_THRESHOLD_BYTES)
                      and libc.mallopt(_M_TRIM_THRESHOLD, 2 * HEAP_THRESHOLD_BYTES))
        except (OSError, AttributeError):  # not glibc
            ok = False
    _DONE.append(ok)
    return ok
