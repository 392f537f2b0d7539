"""The exact accumulator: fixed-point conversion and rounding against Python's exact
arithmetic (fractions, math.fsum), split/order independence where float sums are not, the
range limits, and both backends holding the same integers."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from acquisition.tables import BinAccumulator, IsotropicTable, MerlTable
from acquisition.tables.exact import ExactSums
from acquisition.tables.fixedpoint import (
    FRACTION_BITS,
    LIMB_BITS,
    OutOfRangeError,
    normalize,
    to_float,
    to_limbs,
)

BACKENDS = ("numba", "numpy")


def _integer(limbs: np.ndarray) -> int:
    """The integer a value's (3,) limbs stand for (Python int, no overflow)."""
    return sum(int(x) << (LIMB_BITS * k) for k, x in enumerate(limbs))


def _values(rng: np.random.Generator, n: int) -> np.ndarray:
    """Values over the physical range: BRDF, variances, angles, tiny and negative ones."""
    return rng.normal(0.0, 1.0, n) * 10.0 ** rng.integers(-16, 11, n)


def test_conversion_is_round_to_quantum_and_exact_above_2_to_minus_36():
    rng = np.random.default_rng(1)
    x = np.concatenate([_values(rng, 3000), [0.0, -0.0, 2.0**40 - 2.0**-12, -(2.0**-36),
                                             1.5 * 2.0**-88, 2.5 * 2.0**-88, 2.0**-89]])
    limbs = to_limbs(x)
    for v, lv in zip(x, limbs, strict=True):
        assert _integer(lv) == round(Fraction(float(v)) * 2**FRACTION_BITS), v  # half to even
    exact = np.abs(x) >= 2.0**-36
    np.testing.assert_array_equal(to_float(limbs)[exact], x[exact])
    assert exact.sum() > 1500 and (~exact).sum() > 500


def test_compiled_split_rounds_to_the_same_integer():
    """The numba kernels' three parts (an integer, a multiple of 2^-44, one of 2^-88) add up to
    the integer to_limbs holds, ties to even, from tiny to the largest values; a run's sums of
    RUN_MAX extreme parts are exact in float64."""
    from acquisition.tables.exact_kernels import RUN_MAX, _convert

    rng = np.random.default_rng(1)
    x = np.concatenate([_values(rng, 3000), [0.0, -0.0, 2.0**40 - 2.0**-12, -(2.0**40 - 0.5),
                                             -(2.0**-36), 1.5 * 2.0**-88, 2.5 * 2.0**-88,
                                             -2.5 * 2.0**-88, 2.0**-89, 0.5, -0.5, 1.5 * 2.0**-44]])
    parts = [np.empty(x.size) for _ in range(3)]
    _convert(x, x.size, *parts)
    for v, p0, p1, p2 in zip(x, *parts, strict=True):
        q = [Fraction(float(p)) * 2**FRACTION_BITS for p in (p0, p1, p2)]
        assert all(f.denominator == 1 for f in q)
        assert q[1] % 2**LIMB_BITS == 0 and q[2] % 2**FRACTION_BITS == 0
        assert sum(q) == round(Fraction(float(v)) * 2**FRACTION_BITS), v
    for part, bound, quantum in zip(parts, (2.0**-45, 0.5, 2.0**40), (-88, -44, 0),
                                    strict=True):
        assert np.abs(part).max() <= bound
        steps = int(bound * 2.0**-quantum)  # a run of parts near the bound, one sign mostly
        run = [math.ldexp(int(k), quantum) for k in rng.integers(-steps // 8, steps + 1, RUN_MAX)]
        total = 0.0
        for p in run:  # summed one by one, as a run is
            total += p
        assert Fraction(total) == sum(Fraction(p) for p in run)


def test_a_run_longer_than_run_max_is_summed_in_pieces():
    """One call of the compiled kernel with 5,000 samples of one bin, each of p₁ near ½ (their
    float sum would need 56 bits): the bin holds the exact integer sum all the same."""
    from acquisition.tables import exact_kernels

    rng = np.random.default_rng(9)
    n = 5000
    vals = (0.5 - rng.uniform(0, 2.0**-30, (n, 1))) * rng.choice([1.0, 1.0, 1.0, -1.0], (n, 1))
    store = ExactSums(1, 2)
    tally = np.zeros(4, np.int64)
    assert exact_kernels.add_block(np.zeros(n, np.int64), vals, 0, store.slot, store.rows,
                                   store.count, store.limbs, store.used, tally)
    got = [_integer(limbs) for limbs in normalize(store.limbs[:1].copy())[0]]
    x = vals[:, 0]
    assert got[0] == sum(round(Fraction(float(v)) * 2**FRACTION_BITS) for v in x)
    assert got[1] == sum(round(Fraction(float(v)) * 2**FRACTION_BITS) for v in x * x)  # x²
    assert int(store.count[0]) == n


def test_readout_is_correctly_rounded_ties_included():
    rng = np.random.default_rng(2)
    ints = []
    for bits in rng.integers(1, 148, 4000):
        m = int(rng.integers(1, 2**62)) << max(0, int(bits) - 62) >> max(0, 62 - int(bits))
        if m.bit_length() > 54 and rng.random() < 0.4:  # an exact tie between two floats
            drop = m.bit_length() - 54
            m = (m >> drop << drop) | (1 << (drop - 1)) if rng.random() < 0.5 else m >> drop << drop
        ints.append(-m if rng.random() < 0.5 else m)
    limbs = np.array([[(m >> (LIMB_BITS * k)) & ((1 << LIMB_BITS) - 1) if k < 2
                       else m >> (2 * LIMB_BITS) for k in range(3)] for m in ints], np.int64)
    want = np.array([m / 2**FRACTION_BITS for m in ints])  # Python rounds int / int correctly
    np.testing.assert_array_equal(to_float(limbs), want)
    # Unnormalised limbs (a running sum between carry passes) read the same.
    lazy = limbs.copy()
    lazy[:, 0] += 5 << LIMB_BITS
    lazy[:, 1] -= 5
    np.testing.assert_array_equal(to_float(lazy), want)


@pytest.mark.parametrize("backend", BACKENDS)
def test_bin_sums_are_math_fsum_of_the_samples(backend):
    """Each Σx and Σx² is the correctly rounded exact sum (math.fsum, computed independently)
    of the bin's samples, whatever their order or magnitude."""
    rng = np.random.default_rng(3)
    n = 20_000
    idx = rng.integers(0, 50, n)
    vals = np.stack([_values(rng, n) * 1e-6, rng.uniform(0, 1e4, n), -rng.uniform(0, 1, n)], 1)
    vals[:, 0] = np.clip(vals[:, 0], -1e5, 1e5)
    acc = BinAccumulator((50,), 3, backend=backend)
    acc.add_flat(idx[:7000], vals[:7000])
    acc.add_flat(idx[7000:], vals[7000:])
    for b in range(50):
        sel = vals[idx == b]
        for c in range(3):
            assert acc.sum[b, c] == math.fsum(sel[:, c])
            assert acc.sum_of_squares[b, c] == math.fsum(sel[:, c] * sel[:, c])


def test_backends_hold_the_same_integers_with_lazy_carries_and_runs():
    """Runs of one bin longer than a block, bins past 2^17 additions (carry passes), negative
    values: the stores' canonical partials are equal, limb for limb."""
    rng = np.random.default_rng(4)
    idx = np.concatenate([np.zeros(300_000, np.int64), rng.integers(0, 7, 20_000)])
    vals = np.concatenate([rng.normal(5, 3, (300_000, 3)), rng.normal(0, 1, (20_000, 3))])
    parts = []
    for backend in BACKENDS:
        acc = BinAccumulator((7,), 3, backend=backend)
        acc.add_flat(idx, vals)
        parts.append(acc.partial())
    assert parts[0].same_as(parts[1])
    assert parts[0].count[0] > 300_000
    low = parts[0].limbs[..., :2]
    assert low.min() >= 0 and low.max() < 2**LIMB_BITS  # canonical


def test_more_sums_than_a_padded_block_hold_the_same_integers_in_both_backends():
    """A store of 21 sums (two blocks of exact_kernels.PAD columns, the second partly
    padding): runs past RUN_MAX, a bin past several 2^17-sample carry points (whose second
    block's sums are carried late) and values of both signs and many sizes give the integers
    of the numpy backend (to_limbs per value), limb for limb."""
    from acquisition.tables import exact_kernels

    rng = np.random.default_rng(21)
    k = 21
    assert exact_kernels.PAD < k < 2 * exact_kernels.PAD
    idx = np.concatenate([np.zeros(400_000, np.int64), rng.integers(0, 50, 30_000)])
    vals = rng.normal(0, 1, (idx.size, k)) * 10.0 ** rng.uniform(-9, 9, (idx.size, k))
    stores = []
    for backend in BACKENDS:
        store = ExactSums(50, k, backend=backend)
        assert store.add_values(idx, vals) == idx.size
        stores.append(store.sparse())
    assert stores[0].same_as(stores[1])
    assert int(stores[0].count[0]) > 400_000


def test_float_sums_depend_on_the_split_exact_sums_do_not():
    """The same samples in two batch splits: naive float64 accumulation (what the tables did
    before) gives different sums; the exact accumulator gives the same bits."""
    rng = np.random.default_rng(5)
    n = 30_000
    idx = rng.integers(0, 20, n)
    vals = rng.lognormal(0, 2, (n, 3))
    order = rng.permutation(n)

    def naive(i: np.ndarray, v: np.ndarray, cut: int) -> np.ndarray:
        halves = []
        for a, b in ((0, cut), (cut, i.size)):
            part = np.zeros((20, 3))
            np.add.at(part, i[a:b], v[a:b])
            halves.append(part)
        return halves[0] + halves[1]

    assert not np.array_equal(naive(idx, vals, 1000), naive(idx[order], vals[order], 17_000))
    exact = []
    for i, v, cut in ((idx, vals, 1000), (idx[order], vals[order], 17_000)):
        a, b = BinAccumulator((20,), 3), BinAccumulator((20,), 3)
        a.add_flat(i[:cut], v[:cut])
        b.add_flat(i[cut:], v[cut:])
        b.merge_from(a)
        exact.append(b.sum)
    np.testing.assert_array_equal(exact[0], exact[1])


@pytest.mark.parametrize("backend", BACKENDS)
def test_out_of_range_values_raise_one_line_and_change_nothing(backend):
    table = IsotropicTable(np.arange(0, 91, 30.0), np.arange(0, 91, 30.0), [0, 90, 180],
                           backend=backend)
    table.add(10.0, 10.0, 10.0, [[1.0, 2.0, 3.0]])
    with pytest.raises(OutOfRangeError, match=r"sample value 2\.5e\+06 sr⁻¹ is outside") as err:
        table.add([10.0, 20.0], 10.0, 10.0, [[1.0, 1.0, 1.0], [2.5e6, 1.0, 1.0]])
    assert "\n" not in str(err.value)
    assert table.n_samples == 1 and table.mean[0, 0, 0, 0] == 1.0
    merl = MerlTable(backend=backend)
    with pytest.raises(OutOfRangeError):
        merl.add_halfdiff([10.0], [10.0], [10.0], [[-(2.0**20), 0.0, 0.0]])
    assert merl.n_samples == 0
    merl.add_halfdiff([10.0], [10.0], [10.0], [[np.inf, 1.0, 0.0]])  # not finite: dropped
    assert (merl.n_samples, merl.n_dropped_nan) == (0, 1)
    budget = IsotropicTable([0, 90], [0, 90], [0, 180], backend=backend)
    budget.track_uncertainty({"noise": "n"}, {"white": "w"})
    with pytest.raises(OutOfRangeError, match="uncertainty term 'noise'"):
        budget.add(10.0, 10.0, 10.0, [[1.0, 1.0, 1.0]], variances={"noise": [[2.0**41, 0, 0]]},
                   uncertainties={"white": [[0.0, 0, 0]]})
    assert budget.n_samples == 0


def test_a_sum_that_would_overflow_raises():
    store = ExactSums(1, 1)
    big = normalize(to_limbs(np.array([[2.0**60]])))  # as a stored sum may be
    from acquisition.tables.exact import SparseSums

    part = SparseSums(1, np.array([0]), np.array([1]), big)
    store.merge(part)
    with pytest.raises(OutOfRangeError, match="overflowed"):
        for _ in range(4):
            store.merge(part)


def test_budget_sums_agree_across_backends_and_drop_the_same_samples():
    rng = np.random.default_rng(6)
    n = 5000
    ti, tr, dp = rng.uniform(-5, 95, n), rng.uniform(0, 90, n), rng.uniform(-200, 200, n)
    values = rng.lognormal(-2, 1, (n, 3))
    noise = values**2 * 1e-4
    noise[::97, 1] = np.nan  # a sample without a noise estimate: left out of the budget
    white = values * 1e-3
    parts = []
    for backend in BACKENDS:
        table = IsotropicTable(np.arange(0, 91, 15.0), np.arange(0, 91, 15.0),
                               np.arange(0, 181, 30.0), backend=backend)
        table.track_uncertainty({"noise": "n"}, {"white": "w"})
        for a in range(0, n, 1700):
            s = slice(a, a + 1700)
            table.add(ti[s], tr[s], dp[s], values[s], at=(ti[s] + 0.1, tr[s], dp[s]),
                      variances={"noise": noise[s]}, uncertainties={"white": white[s]})
        parts.append(table.partial())
    assert parts[0].values.same_as(parts[1].values)
    assert parts[0].budget.sums.same_as(parts[1].budget.sums)
    kept = parts[0].budget.sums.count.sum()
    assert 0 < kept < parts[0].values.count.sum()  # the NaN-noise samples are not in it
