"""The fused per-pixel binning (acquisition/reduction/fusedbinning.py) gives the reference
path's tables bit for bit: the same exact limbs, counts, budget sums and drop tallies, on
random frames with samples on bin edges, NaN, ±inf, below the horizon and outside the
isotropic edges, and the same one-line error for a value past the exact sums' range."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from acquisition.reduction import image
from acquisition.reduction.fusedbinning import HELPER_FROM_SAMPLES, bin_frame
from acquisition.reduction.image import FrameSamples, bin_frames
from acquisition.reduction.point import UNCERTAINTY_TERMS
from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.fixedpoint import OutOfRangeError


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.sqrt((v * v).sum(axis=1))[:, None]


def _frame(rng: np.random.Generator, n: int = 6000, variance: bool = True,
           rel: bool = True) -> FrameSamples:
    """Random samples, neighbours often in one bin, with the awkward ones mixed in."""
    wi = _unit(np.repeat(rng.normal(size=(n // 4, 3)) + [0, 0, 1.5], 4, axis=0))
    wo = _unit(rng.normal(size=(wi.shape[0], 3)) * 0.3 + [0.2, -0.1, 1.0])
    brdf = rng.lognormal(-1.0, 1.5, size=wi.shape) * rng.choice([1.0, -1.0], size=wi.shape,
                                                                  p=[0.95, 0.05])
    var = rng.uniform(0.0, 1e-2, size=wi.shape)
    # θi = 0 and 90 exactly, Δφ = ±180 and 0 exactly, grazing and below the horizon
    edge = [([0, 0, 1], [1, 0, 1]), ([1, 0, 0], [0, 1, 1]), ([1, 0, 1], [-1, 0, 1]),
            ([1, 1e-300, 1], [-1, 0, 1]), ([1, 0, 1], [2, 0, 1]), ([1, 0, -0.1], [0, 0, 1]),
            ([0, 0, -1], [0, 0, 1]), ([1, 0, 1], [-1, 0, -1])]
    k = len(edge)
    wi[:k] = _unit(np.array([e[0] for e in edge], float))
    wo[:k] = _unit(np.array([e[1] for e in edge], float))
    bad = rng.choice(np.arange(k, wi.shape[0]), size=60, replace=False)
    for j, what in zip(bad, np.tile([np.nan, np.inf, -np.inf], 20), strict=True):
        target = (wi, wo, brdf, var)[int(rng.integers(4))]
        target[j, rng.integers(3)] = what
    return FrameSamples(0, wi, wo, brdf, var if variance else None,
                        np.array([0.01, 0.02, 0.03]) if rel else None)


def _tables(fold: bool, budget: bool = True) -> tuple[IsotropicTable, MerlTable]:
    dp = np.linspace(0, 180, 19) if fold else np.linspace(-180, 180, 37)
    table = IsotropicTable(np.linspace(0, 90, 10), np.linspace(0, 90, 10), dp)
    if budget:
        table.track_uncertainty(*UNCERTAINTY_TERMS)
    return table, MerlTable()


def assert_same_tables(a: tuple[IsotropicTable, MerlTable],
                       b: tuple[IsotropicTable, MerlTable]) -> None:
    """Both pairs of tables hold the same exact sums, budgets and drop tallies, bit for bit."""
    for x, y in zip(a, b, strict=True):
        px, py = x.partial(), y.partial()
        assert px.values.same_as(py.values)
        assert px.dropped == py.dropped
        assert (px.budget is None) == (py.budget is None)
        if px.budget is not None:
            assert px.budget.sums.same_as(py.budget.sums)


@pytest.mark.parametrize(("fold", "variance", "rel", "budget"),
                         [(True, True, True, True), (False, True, True, True),
                          (True, False, True, True), (True, True, False, True),
                          (False, True, True, False)])
def test_fused_tables_equal_reference_bit_for_bit(fold: bool, variance: bool, rel: bool,
                                                  budget: bool) -> None:
    rng = np.random.default_rng(15)
    frames = [_frame(rng, n, variance=variance, rel=rel)  # the first through the helper thread
              for n in (HELPER_FROM_SAMPLES, 6000, 6000)]
    ref, fused, one = (_tables(fold, budget) for _ in range(3))
    bin_frames(frames, *ref, None, 0, fused=False)
    bin_frames(frames, *fused, None, 0)
    bin_frames(frames, *one, None, 0, threads=False)
    assert_same_tables(ref, fused)
    assert_same_tables(ref, one)
    read = ("std_error", "mean_angles", "angle_covariance") if budget else ()
    for name in ("count", "mean", "variance", *read):
        np.testing.assert_array_equal(getattr(fused[0], name), getattr(ref[0], name))
    assert fused[0].n_dropped_nan > 0 and fused[0].n_dropped_range > 0
    assert fused[1].n_dropped_nan > 0 and fused[1].n_dropped_range > 0
    assert int(fused[0].count.sum()) > 0 and ref[0].mean_angles.shape[:3] == ref[0].shape


def test_empty_frame_changes_nothing() -> None:
    empty = FrameSamples(0, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)),
                         np.zeros((0, 3)), np.array([0.01, 0.02, 0.03]))
    ref, fused = _tables(True), _tables(True)
    assert bin_frames([empty], *fused, None, 0) == bin_frames([empty], *ref, None, 0,
                                                             fused=False) == (0, 1)
    assert_same_tables(ref, fused)
    assert fused[0].n_samples == fused[1].n_samples == 0


def test_fused_in_two_threads_equals_one() -> None:
    rng = np.random.default_rng(16)
    fs = _frame(rng, n=20000)
    one, two = _tables(True), _tables(True)
    assert bin_frame(fs.wi, fs.wo, fs.brdf, fs.variance, fs.calibration_rel, *one)
    with ThreadPoolExecutor(1) as pool:
        assert bin_frame(fs.wi, fs.wo, fs.brdf, fs.variance, fs.calibration_rel, *two, pool)
    assert_same_tables(one, two)


def test_only_frames_of_many_samples_go_to_the_helper_thread(
        monkeypatch: pytest.MonkeyPatch) -> None:
    handed: list[int] = []

    class Spy(ThreadPoolExecutor):
        def submit(self, fn, /, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
            handed.append(args[2].shape[0])  # wi of _merl_then_part
            return super().submit(fn, *args, **kwargs)

    rng = np.random.default_rng(18)
    frames = [_frame(rng, n) for n in (HELPER_FROM_SAMPLES, HELPER_FROM_SAMPLES - 4, 6000)]
    with Spy(1) as spy:
        monkeypatch.setattr(image, "helper_pool", lambda: spy)
        bin_frames(frames, *_tables(True), None, 0)
        assert handed == [HELPER_FROM_SAMPLES]
        bin_frames(frames, *_tables(True), None, 0, threads=False)
    assert handed == [HELPER_FROM_SAMPLES]


@pytest.mark.parametrize("field", ["brdf", "variance"])
def test_out_of_range_raises_the_reference_error(field: str) -> None:
    rng = np.random.default_rng(17)
    fs = _frame(rng)
    getattr(fs, field)[100, 1] = 2.0**41  # past 2^20 sr⁻¹ and past the budget's 2^40
    ref, fused = _tables(True), _tables(True)
    with pytest.raises(OutOfRangeError) as want:
        bin_frames([fs], *ref, None, 0, fused=False)
    with pytest.raises(OutOfRangeError) as got:
        bin_frames([fs], *fused, None, 0)
    assert str(got.value) == str(want.value)
    assert_same_tables(ref, fused)  # a value changes neither table; a budget term leaves the MERL one


@pytest.mark.parametrize("fold", [True, False])
def test_isotropic_index_at_edges_and_the_turn_matches_numpy(fold: bool) -> None:
    """The compiled index's shortcuts (a bin guessed from the edges' span, Δφ mod 360 without
    fmod below one turn) give numpy's bins just beside every edge and ±360°."""
    ei = np.array([0.0, 5.0, 12.5, 30.0, 60.0, 89.0, 90.0])
    ep = np.linspace(0.0, 180.0, 13) if fold else np.linspace(-180.0, 180.0, 25)
    tables = [IsotropicTable(ei, ei, ep, fold_delta_phi=fold, backend=b)
              for b in ("numba", "numpy")]
    def beside(edges: tuple[float, ...]) -> list[float]:
        return [np.nextafter(e, s) for e in edges for s in (-np.inf, np.inf)]

    turn = np.array([*beside((*ep, 360.0, -360.0, 0.0)), *ep, -0.0, -1e-300, 1e-300, 720.0,
                     -540.0, 1e300, -np.inf])
    ti = np.resize(np.array([*beside(tuple(ei)), *ei, np.nan]), turn.size)
    got, want = (t.flat_index(ti, ti[::-1], turn) for t in tables)
    np.testing.assert_array_equal(got, want)
    assert (got >= 0).sum() > turn.size // 3


def test_cached_kernels_dropped_when_a_dependency_changed(tmp_path, monkeypatch) -> None:
    """numba sees a change to the fused kernels' own file only: a digest of the files whose
    functions they call decides whether the cached machine code is still theirs."""
    from acquisition.reduction import binning_kernels

    monkeypatch.setattr(binning_kernels, "_HERE", tmp_path / "binning_kernels.py")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    code = cache / "binning_kernels.iso_frame-70.py311.1.nbc"
    other = cache / "kernels.iso_flat_index-9.py311.nbi"
    for f in (code, other):
        f.write_bytes(b"machine code")
    binning_kernels._drop_stale_cache()  # no digest yet: compiled from unknown sources
    assert not code.exists() and other.exists()
    code.write_bytes(b"machine code")
    binning_kernels._drop_stale_cache()  # same sources: kept
    assert code.exists()
    (cache / "binning_kernels.deps").write_text("another digest")
    binning_kernels._drop_stale_cache()
    assert not code.exists()
