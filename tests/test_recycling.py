"""Recycled frame arrays (calibration/recycling.py): memory comes back once nothing refers to
it, never while an array or a view of it is alive, and the pool stays bounded."""

from __future__ import annotations

import numpy as np
import pytest

from calibration import recycling

BIG = (1024, 1024, 3)  # 24 MiB of float64: pooled


@pytest.fixture(autouse=True)
def empty_pool():
    recycling.clear()
    yield
    recycling.clear()


def _address(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


def test_a_released_buffer_is_handed_out_again() -> None:
    a = recycling.empty(BIG)
    a[...] = 1.0
    where = _address(a)
    del a
    b = recycling.empty(BIG, np.float64)
    assert _address(b) == where
    assert b.shape == BIG and b.dtype == np.float64 and b.flags.c_contiguous
    c = recycling.empty((1000, 1000), np.float32)  # smaller: a new buffer, b is in use
    assert _address(c) != where


def test_memory_in_use_is_never_handed_out() -> None:
    a = recycling.empty(BIG)
    view = a[::2, :, 1]  # a view keeps the buffer
    held = {_address(a)}
    del a
    alive = []
    for _ in range(3):
        alive.append(recycling.empty(BIG))
        assert _address(alive[-1]) not in held
        held.add(_address(alive[-1]))
        alive[-1][...] = 7.0
    assert view.base is not None
    del view, alive
    assert len(recycling._pool) == 4
    assert _address(recycling.empty(BIG)) in held  # all free now: one comes back


def test_small_arrays_are_plain_and_the_pool_is_bounded() -> None:
    small = recycling.empty((100, 3))
    assert small.base is None and recycling.held_bytes() == 0
    kept = [recycling.empty(BIG) for _ in range(recycling.KEEP + 4)]
    assert len(recycling._pool) == recycling.KEEP
    assert recycling.held_bytes() == recycling.KEEP * np.prod(BIG) * 8
    assert len({_address(a) for a in kept}) == len(kept)  # none shared while all are alive
