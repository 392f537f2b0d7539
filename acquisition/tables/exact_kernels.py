"""Numba kernels adding samples into an exact sum store (:mod:`acquisition.tables.exact`).

A store is five arrays: ``slot`` int32 (bins,) the row of each bin (−1: not touched yet),
``rows`` int64 (capacity,) the bin of each row, ``count`` int64 (capacity,), ``limbs`` int64
(capacity, sums, 3) and ``used`` int64 (1,) the rows in use. A sample whose bin has no row yet
takes the next free one. Samples go in blocks of :data:`BLOCK`; before a block a kernel checks
that the store has room for as many new bins, else it stops and returns the sample it stopped
at, the caller grows the store and calls again from there (nothing is lost or added twice).

Every value v is split into three doubles at fixed binary points (:func:`split`; in a
vectorised pass over a block, :func:`_convert`, for the six sums of a value store; inline in
the loop that sums them, :func:`scatter_padded`, for other stores): p₂ = v rounded to an
integer, p₁ = the rest rounded to a multiple of 2^-44, p₀ = what is left rounded to a multiple
of 2^-88, each rounding to nearest, ties to even, by adding and subtracting a constant (exact
but for that rounding, no fast-math). Then p₂·2^88 + p₁·2^88 + p₀·2^88 = round(v·2^88), ties to
even: the integer :func:`acquisition.tables.fixedpoint.to_limbs` gives in numpy, so both
backends hold the same sums. Consecutive samples of one bin (a run: an image fills a bin with
runs of neighbouring pixels) are summed part by part in float64, which is exact: every p₂ is an
integer below 2^40, every p₁ a multiple of 2^-44 below ½, every p₀ a multiple of 2^-88 below
2^-45, so the sums of up to :data:`RUN_MAX` of them need at most 53 bits (a longer run is added
in pieces). At the run's end each part's sum goes to its limb as an integer (p₂'s to the top
limb, p₁'s × 2^44 to the middle one, p₀'s × 2^88 to the low one): one conversion per run and
sum, not per sample. The limbs differ from ``to_limbs``' one by one (signed, rounded), the
integers they hold do not, and the carry pass makes them the same canonical limbs. A bin's
lower limbs get a carry pass whenever its count crosses a multiple of 2^17 (sums past the first
:data:`PAD` of a store, up to a block late); a top limb past the overflow bound is counted in
``tally[3]`` (the caller raises).
"""

from __future__ import annotations

import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels: libm only

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.tables import accumulator, fixedpoint  # noqa: E402

# Compiled code bakes in the globals it reads, and numba's cache is invalidated by a change to
# this file only: so the layout is written out here, and checked against its definitions.
LIMB_BITS = 44
TOP_LIMIT = 1 << 61
CARRY_EVERY = 1 << 18
DROP_NAN = -2
assert (LIMB_BITS, TOP_LIMIT, CARRY_EVERY) == (fixedpoint.LIMB_BITS, fixedpoint.TOP_LIMIT,
                                               fixedpoint.CARRY_EVERY)
assert DROP_NAN == accumulator.DROP_NAN

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
_MASK = (1 << LIMB_BITS) - 1
_ROUND_1 = 1.5 * 2.0**52
"""x + c − c rounds |x| < 2^51 to an integer (to nearest, ties to even)."""
_ROUND_2_44 = 1.5 * 2.0**8
"""... |x| ≤ ½ to a multiple of 2^-44."""
_ROUND_2_88 = 1.5 * 2.0**-36
"""... |x| ≤ 2^-45 to a multiple of 2^-88."""
_TWO_44 = 2.0**44
_TWO_88 = 2.0**88
RUN_MAX = 1 << 10
"""Samples a run may sum in float64 exactly (p₁'s sum stays below 2^9 = 2^53 quanta of 2^-44)."""
_ABS_BITS = np.int64(0x7FFFFFFFFFFFFFFF)
_INF_BITS = np.int64(0x7FF0000000000000)
BLOCK = 256
"""Samples per block: its values are converted in one vectorised pass (the buffers, ~50 kB,
stay in the L1/L2 caches)."""
_CARRY_SHIFT = 17
"""A bin gets a carry pass when its count crosses a multiple of 2^17: with at most RUN_MAX
additions per flush, fewer than CARRY_EVERY = 2^18 additions ever sit on its lower limbs."""
assert (1 << _CARRY_SHIFT) + RUN_MAX <= CARRY_EVERY


@njit(inline="always", **_JIT)
def split(v):  # pragma: no cover - compiled
    """(p₀, p₁, p₂) of v (finite, |v| < 2^40): p₂ an integer, p₁ a multiple of 2^-44, p₀ one
    of 2^-88, whose sum is v rounded to a multiple of 2^-88, ties to even."""
    p2 = (v + _ROUND_1) - _ROUND_1
    r = v - p2
    p1 = (r + _ROUND_2_44) - _ROUND_2_44
    return ((r - p1) + _ROUND_2_88) - _ROUND_2_88, p1, p2


@njit(**_JIT)
def _convert(x, n, f0, f1, f2):  # pragma: no cover - compiled
    """x[q] (q < n) split (:func:`split`) into f0[q], f1[q], f2[q]: a loop LLVM vectorises."""
    for q in range(n):
        f0[q], f1[q], f2[q] = split(x[q])


@njit(**_JIT)
def carry_row(limbs, s):  # pragma: no cover - compiled
    """Carry pass over row ``s`` (fixedpoint.normalize); True when a top limb overflowed."""
    over = False
    for k in range(limbs.shape[1]):
        l0 = limbs[s, k, 0]
        c = l0 >> LIMB_BITS
        limbs[s, k, 0] = l0 & _MASK
        l1 = limbs[s, k, 1] + c
        c = l1 >> LIMB_BITS
        limbs[s, k, 1] = l1 & _MASK
        top = limbs[s, k, 2] + c
        limbs[s, k, 2] = top
        if top >= TOP_LIMIT or top <= -TOP_LIMIT:
            over = True
    return over


@njit(inline="always", **_JIT)
def _row(b, slot, rows, used):  # pragma: no cover - compiled
    """Row of bin ``b``, a new one if it has none (the caller made room)."""
    s = slot[b]
    if s < 0:
        s = used[0]
        slot[b] = s
        rows[s] = b
        used[0] = s + 1
    return s


@njit(**_JIT)
def flush(s, run, acc, count, limbs, tally, first=0):  # pragma: no cover - compiled
    """Add a run's exact float sums ``acc`` (3, ·) of their parts (rows p₀, p₁, p₂), for the
    store's sums ``first`` … (as many as ``acc`` has columns and the store has sums), to row
    ``s``'s limbs, and zero ``acc``; the sums from 0 also count the run's ``run`` samples."""
    for k in range(min(acc.shape[1], limbs.shape[1] - first)):
        limbs[s, first + k, 0] += np.int64(acc[0, k] * _TWO_88)
        limbs[s, first + k, 1] += np.int64(acc[1, k] * _TWO_44)
        limbs[s, first + k, 2] += np.int64(acc[2, k])
    acc[:] = 0.0
    if first:
        return
    before = count[s]
    count[s] = before + run
    if (before >> _CARRY_SHIFT) != ((before + run) >> _CARRY_SHIFT) and carry_row(limbs, s):
        tally[3] += 1


@njit(**_JIT)
def _scatter(x, bins, n, slot, rows, count, limbs, used, tally):  # pragma: no cover
    """Add value row j (entries j·K … j·K + K − 1 of ``x``; K sums) to bin ``bins[j]`` for
    j < n, consecutive samples of one bin summed first (images fill a bin with runs of
    pixels), at most :data:`RUN_MAX` at a time. Six sums go through :func:`_scatter6`;
    others through :func:`scatter_padded` (a copy padded with zeros), which splits each value
    and adds its parts to the run's sums."""
    k_sums = limbs.shape[1]
    if k_sums == 6:
        f0, f1, f2 = np.empty(6 * n), np.empty(6 * n), np.empty(6 * n)
        _convert(x, 6 * n, f0, f1, f2)
        _scatter6(bins, n, f0, f1, f2, slot, rows, count, limbs, used, tally)
        return
    width = -(-k_sums // PAD) * PAD
    padded = np.zeros((n, width))
    padded[:, :k_sums] = x[:n * k_sums].reshape(n, k_sums)
    scatter_padded(padded, bins, n, slot, rows, count, limbs, used, tally)


PAD = 16
"""Columns of :func:`scatter_padded`'s blocks of values."""


@njit(**_JIT)
def scatter_padded(x, bins, n, slot, rows, count, limbs, used, tally):  # pragma: no cover
    """:func:`_scatter` of the first n rows of x (·, W), each row a sample's K sums (K =
    the store's) then zeros up to W, a multiple of :data:`PAD`: one pass over the samples per
    block of PAD columns, whose loop over a row has a constant length, which LLVM turns into
    whole vectors (the budget's 15 sums take one block). The first block's runs count the
    samples and trigger the carry passes, so later blocks' sums get theirs up to n samples
    late: n ≤ 2^16 keeps them within CARRY_EVERY's margin."""
    assert n <= 1 << 16
    acc = np.zeros((3, PAD))
    for c in range(0, x.shape[1], PAD):
        current, s, run = -1, -1, 0
        for j in range(n):
            b = bins[j]
            if b != current or run == RUN_MAX:  # a run's float sums stay exact
                if run:
                    flush(s, run, acc, count, limbs, tally, c)
                current, s, run = b, _row(b, slot, rows, used), 0
            for k in range(PAD):
                p0, p1, p2 = split(x[j, c + k])
                acc[0, k] += p0
                acc[1, k] += p1
                acc[2, k] += p2
            run += 1
        if run:
            flush(s, run, acc, count, limbs, tally, c)
    tally[0] += n


@njit(inline="always", **_JIT)
def _plus6(acc, f, q):  # pragma: no cover - compiled
    """The six sums ``acc`` plus f[q … q + 5] (a tuple: numba keeps it in registers)."""
    return (acc[0] + f[q], acc[1] + f[q + 1], acc[2] + f[q + 2], acc[3] + f[q + 3],
            acc[4] + f[q + 4], acc[5] + f[q + 5])


_ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(**_JIT)
def _scatter6(bins, n, f0, f1, f2, slot, rows, count, limbs, used, tally):  # pragma: no cover
    """:func:`_scatter` for six sums (x, x² of RGB), the run's sums of each part held in
    registers (numba keeps scalars, not a small array, in registers: twice as fast); a
    negative bin is a sample this store leaves out."""
    low = mid = top = _ZERO6  # the sums of the p₀, p₁ and p₂ parts
    current, s, run, added = -1, -1, 0, 0
    for j in range(n + 1):
        b = bins[j] if j < n else -1
        if b < 0 and j < n:  # a sample this store drops (pixelbinning: one of its tables)
            continue
        if j == n or b != current or run == RUN_MAX:  # a run's float sums stay exact
            if run:
                _flush6(s, run, low, mid, top, count, limbs, tally)
                low = mid = top = _ZERO6
            if j == n:
                break
            current, s, run = b, _row(b, slot, rows, used), 0
        q = 6 * j
        low, mid, top = _plus6(low, f0, q), _plus6(mid, f1, q), _plus6(top, f2, q)
        run += 1
        added += 1
    tally[0] += added


@njit(inline="always", **_JIT)
def _flush6(s, run, low, mid, top, count, limbs, tally):  # pragma: no cover - compiled
    """:func:`flush` of a run's six sums given as tuples of their parts' exact float sums."""
    for k in range(6):
        limbs[s, k, 0] += np.int64(low[k] * _TWO_88)
        limbs[s, k, 1] += np.int64(mid[k] * _TWO_44)
        limbs[s, k, 2] += np.int64(top[k])
    before = count[s]
    count[s] = before + run
    if (before >> _CARRY_SHIFT) != ((before + run) >> _CARRY_SHIFT) and carry_row(limbs, s):
        tally[3] += 1


@njit(**_JIT)
def _room(n, slot, rows, used):  # pragma: no cover - compiled
    """True when ``n`` new bins fit (or the store already spans the grid)."""
    return rows.size >= slot.size or rows.size - used[0] >= n


@njit(**_JIT)
def add_block(idx, vals, start, slot, rows, count, limbs, used, tally):  # pragma: no cover
    """Add sample ``start + j`` (value x and x² per channel) to bin ``idx[j]`` (j < BLOCK);
    tally kept (``tally[0]``), NaN (``[1]``: DROP_NAN or a non-finite channel sum, the numpy
    path's test) and out of range (``[2]``). Returns False, having done nothing, when the
    store may not have room for the block's bins."""
    if not _room(idx.size, slot, rows, used):
        return False
    n_bins = slot.size
    channels = vals.shape[1]
    k_sums = 2 * channels
    x = np.empty(idx.size * k_sums)
    bins = np.empty(idx.size, np.int64)
    n = 0
    for j in range(idx.size):
        b = idx[j]
        i = start + j
        total = 0.0
        for c in range(channels):
            total += vals[i, c]
        if b == DROP_NAN or not np.isfinite(total):
            tally[1] += 1
        elif b < 0 or b >= n_bins:
            tally[2] += 1
        else:
            q = n * k_sums
            for c in range(channels):
                v = vals[i, c]
                x[q + c] = v
                x[q + channels + c] = v * v
            bins[n] = b
            n += 1
    _scatter(x, bins, n, slot, rows, count, limbs, used, tally)
    return True


@njit(**_JIT)
def add_flat(idx, vals, slot, rows, count, limbs, used, tally, start):  # pragma: no cover
    """:func:`add_block` over every sample from ``start``; returns where it stopped."""
    for a in range(start, idx.size, BLOCK):
        m = min(BLOCK, idx.size - a)
        if not add_block(idx[a:a + m], vals, a, slot, rows, count, limbs, used, tally):
            return a
    return idx.size


@njit(**_JIT)
def add_sums(idx, vals, slot, rows, count, limbs, used, tally, start):  # pragma: no cover
    """Add row ``i`` of ``vals`` (every column a sum of its own, no squares) to bin
    ``idx[i]`` for i from ``start``; the indices are valid and the values finite (the caller
    filtered). Returns where it stopped (the store needs room)."""
    k_sums = vals.shape[1]
    for a in range(start, idx.size, BLOCK):
        m = min(BLOCK, idx.size - a)
        if not _room(m, slot, rows, used):
            return a
        x = np.ascontiguousarray(vals[a:a + m]).reshape(m * k_sums)
        _scatter(x, idx[a:a + m], m, slot, rows, count, limbs, used, tally)
    return idx.size


@njit(**_JIT)
def _budget_row(terms, angles, i, x, q):  # pragma: no cover - compiled
    """A budget's sums of sample ``i`` into x[q …]: its terms, its angles and their six
    products (uncertainty.UncertaintySums order); False when one is not finite."""
    k = 0
    for c in range(terms.shape[1]):
        x[q + k] = terms[i, c]
        k += 1
    a0, a1, a2 = angles[i, 0], angles[i, 1], angles[i, 2]
    for v in (a0, a1, a2, a0 * a0, a1 * a1, a2 * a2, a0 * a1, a0 * a2, a1 * a2):
        x[q + k] = v
        k += 1
    ok = True
    for j in range(k):
        ok = ok and np.isfinite(x[q + j])
    return ok


@njit(**_JIT)
def budget_largest(idx, terms, angles):  # pragma: no cover - compiled
    """(largest |term|, largest |angle|) over the samples :func:`add_budget` keeps."""
    x = np.empty(terms.shape[1] + 9)
    big_term, big_angle = 0.0, 0.0
    for i in range(idx.size):
        if idx[i] >= 0 and _budget_row(terms, angles, i, x, 0):
            for c in range(terms.shape[1]):
                big_term = max(big_term, abs(x[c]))
            for c in range(3):
                big_angle = max(big_angle, abs(angles[i, c]))
    return big_term, big_angle


@njit(**_JIT)
def add_budget(idx, terms, angles, slot, rows, count, limbs, used, tally,
               start):  # pragma: no cover - compiled
    """Add each sample's budget (its term values, angles and angle products) to bin
    ``idx[i]`` for i from ``start``; samples with a negative index or a non-finite value are
    left out. Returns where it stopped (the store needs room)."""
    k_sums = limbs.shape[1]
    x = np.empty(BLOCK * k_sums)
    bins = np.empty(BLOCK, np.int64)
    for a in range(start, idx.size, BLOCK):
        m = min(BLOCK, idx.size - a)
        if not _room(m, slot, rows, used):
            return a
        n = 0
        for j in range(m):
            if idx[a + j] >= 0 and _budget_row(terms, angles, a + j, x, n * k_sums):
                bins[n] = idx[a + j]
                n += 1
        _scatter(x, bins, n, slot, rows, count, limbs, used, tally)
    return idx.size


@njit(**_JIT)
def max_finite_abs(vals):  # pragma: no cover - compiled
    """Largest |v| over the finite entries of a 2-D array (0 for none). Compared as the
    integers of their bit patterns (sign cleared, which order non-negative doubles as their
    values do; finite below the exponent of inf): an integer maximum, which LLVM vectorises
    where a float one without fast-math does not."""
    bits = np.ascontiguousarray(vals).reshape(vals.size).view(np.int64)
    largest = np.int64(0)
    for q in range(bits.size):
        b = bits[q] & _ABS_BITS
        largest = b if (b < _INF_BITS) & (b > largest) else largest
    return np.array([largest]).view(np.float64)[0]
