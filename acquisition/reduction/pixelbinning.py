"""A linearized frame's pixels straight into the MERL and isotropic tables, on both cores, with
no per-sample arrays (:mod:`.pixelbinning_kernels`).

:func:`~acquisition.reduction.imaging.pixel_samples` then
:func:`~acquisition.reduction.fusedbinning.bin_frame` give the same tables bit for bit (their
reference; ``tests/test_pixel_binning.py``), but write and read back every sample's directions,
BRDF and variance (~300 MB for a 24 MP frame) and do all the work after the frame is decoded.

Here the work that needs only the pose (each pixel's geometry, MERL bin, pose and isotropic
bin: :class:`GeometryJob`) can start before the frame is decoded, on the helper thread while
the calling thread decodes (:meth:`GeometryJob.start`); then both threads take blocks of rows
in turn, each binning the valid pixels into tables of its own; those are checked, then merged
into the caller's tables (exact sums: any split gives the same integers). The checks are those
of ``bin_frame``: a BRDF value with |f| ≥ 2^20 sr⁻¹ raises before either table changes, and a
budget that could reach the exact sums' range sends the frame to the reference path
(:func:`bin_pixels` returns None, having changed nothing).
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import SampleConfig
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.reduction.fusedbinning import HELPER_FROM_SAMPLES, fits, maxima_in_range
from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.exact import ExactSums
from acquisition.tables.fixedpoint import max_finite_abs
from calibration import recycling

CHUNKS = 24
"""Blocks of rows (of about equal work) the threads take in turn: the cost of a pixel varies
over the frame (MERL bins per row, invalid pixels), so equal halves would not finish
together."""


@dataclass
class _Part:
    """One thread's tables and what its pass found."""

    table: IsotropicTable
    merl: MerlTable
    found: np.ndarray  # samples, largest finite |f|, largest finite variance


class _Chunks:
    """Blocks of rows handed out in order, one at a time, to whichever thread asks."""

    def __init__(self, bounds: np.ndarray) -> None:
        self._bounds = [int(b) for b in bounds]
        self._next = 0
        self._lock = threading.Lock()

    def cancel(self) -> None:
        """Hand out nothing more."""
        with self._lock:
            self._next = len(self._bounds)

    def take(self) -> tuple[int, int] | None:
        with self._lock:
            i = self._next
            if i + 1 >= len(self._bounds):
                return None
            self._next = i + 1
            return self._bounds[i], self._bounds[i + 1]


def _new_part(table: IsotropicTable, merl: MerlTable) -> _Part:
    part = table._empty_like()
    if table.tracks_uncertainty:
        part.track_uncertainty(*(dict(terms) for terms in table._budget_terms()))
    return _Part(part, MerlTable(merl.provenance, backend=merl.backend), np.zeros(3))


def _stores(part: _Part) -> tuple[ExactSums, ExactSums, ExactSums]:
    """The part's isotropic value store, budget store (a scratch one when it tracks none)
    and MERL store."""
    from acquisition.reduction.binning_kernels import BUDGET_SUMS

    unc = part.table._unc
    budget = unc._sums if unc is not None else ExactSums(1, BUDGET_SUMS)
    return part.table._acc._sums, budget, part.merl._acc._sums


def _arrays(store: ExactSums, tally: np.ndarray) -> tuple[np.ndarray, ...]:
    return store.slot, store.rows, store.count, store.limbs, store.used, tally


class GeometryJob:
    """The candidates of one frame's pose and image shape (:func:`.pixelbinning_kernels.
    geometry_rows`), computed in blocks of rows by whichever threads call :meth:`run`."""

    def __init__(self, camera: PinholeCamera, light_pos: np.ndarray, sample: SampleConfig,
                 shape: tuple[int, int], min_cos: float, table: IsotropicTable) -> None:
        from acquisition.reduction.imaging import frame_parameters
        from acquisition.reduction.sample_kernels import column_x
        from acquisition.reduction.sample_spans import row_spans

        p = frame_parameters(camera, light_pos, sample)
        self.shape = (int(shape[0]), int(shape[1]))
        spans = row_spans(p, self.shape)
        width = np.maximum(spans[1] - spans[0], 0)
        total = int(width.sum())
        offsets = np.concatenate([[0], np.cumsum(width)]).astype(np.int64)
        self.frame = (p, column_x(p, self.shape[1]), float(min_cos))
        self.spans = spans
        self.pixels = total
        self.arrays = (offsets, np.zeros(self.shape[0], np.int64),
                       recycling.empty(total, np.int64), recycling.empty(total),
                       recycling.empty(total, np.int64), recycling.empty(total, np.int64),
                       recycling.empty(total), recycling.empty(total), recycling.empty(total))
        self.edges = (table.theta_i_edges, table.theta_r_edges, table.delta_phi_edges,
                      bool(table.fold_delta_phi))
        self._chunks = _Chunks(_balanced(width, CHUNKS))
        self._helper: Future[None] | None = None

    def run(self) -> None:
        """Compute blocks of rows until none is left."""
        from acquisition.reduction.pixelbinning_kernels import geometry_rows

        offsets, ncand, *rest = self.arrays
        while (rows := self._chunks.take()) is not None:
            geometry_rows(self.frame, self.spans, rows[0], rows[1], offsets, ncand, *rest,
                          *self.edges)

    def start(self, pool: ThreadPoolExecutor) -> GeometryJob:
        """Begin in ``pool``'s thread (while the caller decodes the frame)."""
        self._helper = pool.submit(self.run)
        return self

    def finish(self) -> None:
        """Compute what is left on this thread too, and wait for the helper's share."""
        self.run()
        if self._helper is not None:
            self._helper.result()

    def cancel(self) -> None:
        """Hand out no more rows, and wait for the helper's block (the frame went another
        way)."""
        self._chunks.cancel()
        if self._helper is not None:
            self._helper.result()


def _run(part: _Part, chunks: _Chunks, frame: tuple, variance: np.ndarray | None,
         geometry: GeometryJob, rel: np.ndarray, budget: bool) -> None:
    """Bin blocks of rows into the part's tables until none is left, growing its stores
    whenever the pass stops for room."""
    from acquisition.reduction.pixelbinning_kernels import BATCH, value_rows
    from acquisition.tables.exact import _raise_if_overflow

    stores = _stores(part)
    tallies = [np.zeros(4, np.int64) for _ in stores]
    for store in stores:
        store._touch()
    part.table._stored = None
    part.table._stored_scatter = None
    need = BATCH + geometry.shape[1]
    while (rows := chunks.take()) is not None:
        row, stop = rows
        while row < stop:
            row = int(value_rows(frame, variance, row, stop, geometry.arrays, rel, budget,
                                 *(_arrays(s, t) for s, t in zip(stores, tallies, strict=True)),
                                 part.found))
            if row < stop:
                for store in stores:
                    store.grow(need)
    _raise_if_overflow(*tallies)
    value, _, merl = tallies
    part.table._acc.n_dropped_nan += int(value[1])
    part.table._acc.n_dropped_range += int(value[2])
    part.merl._acc.n_dropped_nan += int(merl[1])
    part.merl._acc.n_dropped_range += int(merl[2])


def _balanced(width: np.ndarray, parts: int) -> np.ndarray:
    """Row bounds of ``parts`` blocks of about equal work (pixels in the spans)."""
    from acquisition.reduction.imaging import _balanced as balanced

    return balanced(width, 0, width.size, parts)


def bin_pixels(camera: PinholeCamera, light_pos: np.ndarray, sample: SampleConfig,
               rgb: np.ndarray, valid: np.ndarray, variance: np.ndarray | None,
               calibration: np.ndarray, calibration_rel: np.ndarray | None, min_cos: float,
               table: IsotropicTable, merl: MerlTable,
               pool: ThreadPoolExecutor | None = None,
               geometry: GeometryJob | None = None) -> int | None:
    """Bin the BRDF samples of a linearized frame (``rgb``, ``variance``: (rows, columns, 3),
    DN/s and its square; ``valid`` (rows, columns); C (3,) and its relative u (3,)) into both
    tables: the samples ``pixel_samples`` gives, binned as ``bin_frame`` bins them, the work
    shared with ``pool``'s thread when given (large frames). ``geometry``: this frame's pose's
    :class:`GeometryJob`, perhaps started already (one for another image shape is dropped).
    Returns the samples binned, or None, having changed nothing, when the fused kernels do
    not apply (:func:`fits`, the budget's range): take the reference path then."""
    valid = np.ascontiguousarray(valid)
    h, w = valid.shape
    usable = fits(table, merl)
    if geometry is not None and (geometry.shape != (h, w) or not usable):
        geometry.cancel()  # started for another image size, or not to be used
        geometry = None
    if not usable:
        return None
    if geometry is None:
        geometry = GeometryJob(camera, light_pos, sample, (h, w), min_cos, table)
        if pool is not None and geometry.pixels >= HELPER_FROM_SAMPLES:
            geometry.start(pool)
    geometry.finish()
    var = None if variance is None else np.ascontiguousarray(variance).reshape(h, 3 * w)
    frame = (np.ascontiguousarray(rgb).reshape(h, 3 * w), valid,
             np.ascontiguousarray(calibration, dtype=np.float64))
    rel = (np.full(3, np.nan) if calibration_rel is None
           else np.ascontiguousarray(calibration_rel, np.float64).reshape(3))
    budget = table.tracks_uncertainty and var is not None
    threads = 2 if pool is not None and geometry.pixels >= HELPER_FROM_SAMPLES else 1
    ncand = geometry.arrays[1]
    chunks = _Chunks(_balanced(ncand, CHUNKS if threads == 2 else 1))
    parts = [_new_part(table, merl) for _ in range(threads)]
    args = (chunks, frame, var, geometry, rel, budget)
    helper = pool.submit(_run, parts[1], *args) if threads == 2 else None  # type: ignore[union-attr]
    try:
        _run(parts[0], *args)
    finally:
        if helper is not None:
            helper.result()
    largest_f = max(float(part.found[1]) for part in parts)
    largest_var = max(float(part.found[2]) for part in parts)
    merl._acc._check_values(np.empty((0, 3)), largest_f)  # bin_frame's checks, same messages
    if table.tracks_uncertainty and not maxima_in_range(
            largest_f, None if var is None else largest_var,
            float(max_finite_abs(rel.reshape(1, 3)))):
        return None
    for part in parts:
        table.merge_partial(part.table.partial())
        merl.merge_partial(part.merl.partial())
    return int(sum(part.found[0] for part in parts))
