"""Large per-frame arrays handed out again once nothing else holds them.

A 24 MP frame's reduction fills ~0.6 GB of fresh arrays (the linearized image and its
variance, every sample's directions and BRDF). Fresh memory comes from the kernel one zeroed
page at a time: about a third of the frame's reduction went to page faults (``perf stat``:
~19,000 faults and 0.16 s of system time a frame). :func:`empty` returns an array backed by a
buffer of an earlier frame instead, when no array, view or object refers to that buffer any
more (its reference count says so), so recycling can never hand out memory still in use: a
caller that keeps a frame's arrays simply gets new ones for the next frame.

The pool keeps at most :data:`KEEP` buffers (the most recently used); memory held between
frames is one or two frames' arrays, never more.
"""

from __future__ import annotations

import sys
import threading

import numpy as np

MIN_BYTES = 1 << 22
"""Arrays smaller than this (4 MiB) are plain ``np.empty``: malloc reuses their memory."""
KEEP = 12
"""Buffers the pool keeps (a frame takes up to ten: image, variance and validity, then the
per-pixel geometry's seven arrays or the samples' six)."""
_FREE_REFS = 3
"""``sys.getrefcount`` of a pooled buffer nothing else refers to: the pool's list, the loop
variable and the call's own argument."""

_lock = threading.Lock()
_pool: list[np.ndarray] = []


def empty(shape: int | tuple[int, ...], dtype: np.dtype | type = np.float64) -> np.ndarray:
    """An uninitialised C-contiguous array, like ``np.empty``, backed by a free pooled buffer
    where one is large enough (the smallest such; a view of its first bytes)."""
    dt = np.dtype(dtype)
    shape = (shape,) if isinstance(shape, int) else tuple(int(s) for s in shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
    if nbytes < MIN_BYTES:
        return np.empty(shape, dt)
    with _lock:
        at = -1
        for i in range(len(_pool)):  # not enumerate: its tuple would hold a reference
            buf = _pool[i]
            if buf.nbytes >= nbytes and sys.getrefcount(buf) == _FREE_REFS and (
                    at < 0 or buf.nbytes < _pool[at].nbytes):
                at = i
        if at < 0:
            _pool.append(np.empty(nbytes, np.uint8))
            _evict()
        else:
            _pool.append(_pool.pop(at))  # most recently used last
        return _pool[-1][:nbytes].view(dt).reshape(shape)


def _evict() -> None:
    """Forget the least recently used buffers past :data:`KEEP` (those in use stay alive
    through their views, and are freed with them)."""
    while len(_pool) > KEEP:
        _pool.pop(0)


def clear() -> None:
    """Forget every pooled buffer (their memory is freed once no array uses it)."""
    with _lock:
        _pool.clear()


def held_bytes() -> int:
    """Bytes of the pooled buffers (free or in use)."""
    with _lock:
        return sum(buf.nbytes for buf in _pool)
