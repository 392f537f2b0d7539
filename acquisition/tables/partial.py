"""Partial tables: the exact sums of some frames of a reduction, mergeable and savable.

A :class:`TablePartial` is one table's exact sums (count, Σx, Σx² per bin and channel; for an
isotropic table that tracks uncertainty, its budget's sums too) over the bins its samples
touched, in canonical form (:class:`~acquisition.tables.exact.SparseSums`). A
:class:`ReductionPartial` holds the partial tables of a set of frames (journal steps) of one
reduction. Merging adds integers: any split of a session's frames into partials, merged in any
order and grouping, gives the same arrays — and the finished table, rounded once, the same
bytes as a single sequential reduction.

Files (``gonio-partial-tables`` version 1, HDF5, written through
:func:`drivers.storage.atomic_output`: temporary file in the same folder, fsync, rename):

==========================  =====================================================
name                        meaning
==========================  =====================================================
steps                       int64 [n]: the journal steps (first step of each frame) inside
TABLE/bins, count           int64 [m]: touched flat bins, increasing, and their samples
TABLE/limbs                 int64 [m, K, 3]: normalised fixed-point limbs of the K sums
TABLE/theta_i_edges …       the isotropic grid (θi, θr, Δφ edges, deg; ``@fold_delta_phi``)
TABLE/budget/bins, count,   the budget's sums (``@independent``, ``@correlated``: JSON
limbs                       lists of [name, description])
TABLE@kind                  "isotropic" or "merl"; ``@dropped_nan``, ``@dropped_range``
frame_data/STEP/NAME        a frame's arrays the reduction needs at the end (frame-bins)
@format, @version           "gonio-partial-tables", 1
@key                        what reduction the partial belongs to (session, calibration, …)
@samples                    BRDF samples taken from the frames
@gonio, @numpy, @numba      the versions that made it: a load by other versions is refused
@limb_bits, @fraction_bits  the fixed-point layout (44, 88)
==========================  =====================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.tables.exact import SparseSums
from acquisition.tables.fixedpoint import FRACTION_BITS, LIMB_BITS
from drivers.errors import GonioError
from drivers.storage import atomic_output

FORMAT = "gonio-partial-tables"
VERSION = 1
WHAT = "partial tables"
FRAME_DATA = "frame_data"
"""The group holding each frame's arrays (``frame_data/STEP/NAME``)."""
SOFTWARE = ("gonio", "numpy", "numba")
"""Packages whose versions a partial records and a load must match."""


class PartialError(GonioError, ValueError):
    """Partials that cannot be merged or loaded (other reduction, other versions, overlap)."""


def software_versions() -> dict[str, str]:
    """Installed versions of :data:`SOFTWARE` (read from the metadata, nothing imported)."""
    out = {}
    for name in SOFTWARE:
        try:
            out[name] = version(name)
        except PackageNotFoundError:  # pragma: no cover - a bare source tree
            out[name] = "unknown"
    return out


@dataclass(frozen=True)
class BudgetPartial:
    """An isotropic table's uncertainty budget sums: term (name, description) pairs, then the
    exact sums (:class:`~acquisition.tables.uncertainty.UncertaintySums` order)."""

    independent: tuple[tuple[str, str], ...]
    correlated: tuple[tuple[str, str], ...]
    sums: SparseSums

    def merge(self, other: BudgetPartial) -> BudgetPartial:
        if (self.independent, self.correlated) != (other.independent, other.correlated):
            raise PartialError("cannot merge partial budgets with different uncertainty terms")
        return replace(self, sums=self.sums.merge(other.sums))


@dataclass(frozen=True)
class TablePartial:
    """One table's exact sums: ``kind`` "isotropic" (with its ``grid``: edges in degrees and
    ``fold_delta_phi``) or "merl", the values' sums, the (NaN, out-of-range) drop tallies and
    the budget (isotropic tables that track uncertainty)."""

    kind: str
    values: SparseSums
    dropped: tuple[int, int] = (0, 0)
    grid: Mapping[str, Any] = field(default_factory=dict)
    budget: BudgetPartial | None = None

    def merge(self, other: TablePartial) -> TablePartial:
        """The sums of both (same kind, grid and budget terms)."""
        if self.kind != other.kind or not _same_grid(self.grid, other.grid):
            raise PartialError(f"cannot merge a {self.kind} partial table with a {other.kind} one "
                               "of another grid: bin both with the same edges")
        if (self.budget is None) != (other.budget is None):
            raise PartialError("cannot merge a partial table that tracks uncertainty with one "
                               "that does not")
        budget = None if self.budget is None else self.budget.merge(other.budget)  # type: ignore[arg-type]
        dropped = (self.dropped[0] + other.dropped[0], self.dropped[1] + other.dropped[1])
        return replace(self, values=self.values.merge(other.values), dropped=dropped,
                       budget=budget)


@dataclass(frozen=True)
class ReductionPartial:
    """The partial tables (by name, e.g. "isotropic", "merl") of the frames ``steps`` of the
    reduction ``key``, and the BRDF samples those frames gave."""

    key: str
    steps: frozenset[int]
    tables: Mapping[str, TablePartial]
    samples: int = 0
    frame_data: Mapping[int, Mapping[str, np.ndarray]] = field(default_factory=dict)
    """Per frame (journal step): named arrays the reduction needs whole at the end (an
    image-based reduction's frame-bins and their angular terms); merged by union."""

    def merge(self, other: ReductionPartial) -> ReductionPartial:
        """Both partials' frames (disjoint) of the same reduction."""
        if self.key != other.key:
            raise PartialError("cannot merge partials of different reductions (session, "
                               "calibration or options differ)")
        if set(self.tables) != set(other.tables):
            raise PartialError(f"cannot merge partials of tables {sorted(self.tables)} and "
                               f"{sorted(other.tables)}")
        twice = sorted(self.steps & other.steps)
        if twice:
            raise PartialError(f"cannot merge partials that both hold frame(s) {twice[:5]}: "
                               "each frame must be reduced once")
        tables = {k: t.merge(other.tables[k]) for k, t in self.tables.items()}
        return ReductionPartial(self.key, self.steps | other.steps, tables,
                                self.samples + other.samples,
                                {**self.frame_data, **other.frame_data})


def merge_all(partials: list[ReductionPartial]) -> ReductionPartial:
    """All partials merged (any order and grouping gives the same)."""
    if not partials:
        raise PartialError("no partial to merge")
    out = partials[0]
    for p in partials[1:]:
        out = out.merge(p)
    return out


def _same_grid(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    return set(a) == set(b) and all(np.array_equal(np.asarray(a[k]), np.asarray(b[k])) for k in a)


# ---------------------------------------------------------------------------- files
def is_partial_file(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a ``gonio-partial-tables`` file (one gonio may replace)."""
    try:
        with h5py.File(path, "r") as f:
            return _text(f.attrs.get("format")) == FORMAT
    except (OSError, ValueError):
        return False


def save_partial(path: str | os.PathLike[str], partial: ReductionPartial,
                 inputs: tuple[str | os.PathLike[str], ...] = ()) -> Path:
    """Write ``partial`` atomically (never a half-written file under ``path``); an existing
    partial file is replaced, any other file refused."""
    path = Path(path)

    def verify(tmp: Path) -> None:
        with h5py.File(tmp, "r") as f:
            if _text(f.attrs.get("format")) != FORMAT or f["steps"].shape != (len(partial.steps),):
                raise ValueError("format attribute or steps missing")

    with atomic_output(path, what=WHAT, verify=verify, ours=is_partial_file,
                       inputs=inputs) as tmp, h5py.File(tmp, "w") as f:
        f.create_dataset("steps", data=np.array(sorted(partial.steps), np.int64))
        for name, table in partial.tables.items():
            _write_table(f.create_group(name), table)
        frames = f.create_group(FRAME_DATA)
        for step, arrays in partial.frame_data.items():
            g = frames.create_group(str(int(step)))
            for name, data in arrays.items():
                g.create_dataset(name, data=np.asarray(data))
        f.attrs.update({"format": FORMAT, "version": np.int64(VERSION), "key": partial.key,
                        "samples": np.int64(partial.samples), "limb_bits": np.int64(LIMB_BITS),
                        "fraction_bits": np.int64(FRACTION_BITS), **software_versions()})
    return path


def _write_sums(group: h5py.Group, sums: SparseSums) -> None:
    group.attrs["n_bins"] = np.int64(sums.n_bins)
    for name in ("bins", "count", "limbs"):
        data = getattr(sums, name)
        group.create_dataset(name, data=data, **({"compression": "lzf", "shuffle": True}
                                                  if data.size > 4096 else {}))


def _write_table(group: h5py.Group, table: TablePartial) -> None:
    _write_sums(group, table.values)
    group.attrs.update({"kind": table.kind, "dropped_nan": np.int64(table.dropped[0]),
                        "dropped_range": np.int64(table.dropped[1])})
    for name, value in table.grid.items():
        if np.ndim(value):
            group.create_dataset(name, data=np.asarray(value, np.float64))
        else:
            group.attrs[name] = value
    if table.budget is not None:
        b = group.create_group("budget")
        _write_sums(b, table.budget.sums)
        b.attrs["independent"] = json.dumps([list(t) for t in table.budget.independent])
        b.attrs["correlated"] = json.dumps([list(t) for t in table.budget.correlated])


def load_partial(path: str | os.PathLike[str]) -> ReductionPartial:
    """Read a partial file. Refused (:class:`PartialError`, one line) when it is not one, or
    when gonio, numpy or numba differ from the versions that wrote it."""
    path = Path(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise PartialError(f"partial {path} cannot be read ({exc}): delete it") from None
    with f:
        fmt = _text(f.attrs.get("format"))
        if fmt != FORMAT or int(f.attrs.get("version", 0)) != VERSION:
            raise PartialError(f"{path} is not a {FORMAT} v{VERSION} file (format {fmt!r}): "
                               "delete it or pass a partial gonio wrote")
        _check_versions(f, path)
        steps = frozenset(int(s) for s in f["steps"][()])
        tables = {name: _read_table(g) for name, g in f.items()
                  if isinstance(g, h5py.Group) and name != FRAME_DATA}
        frame_data = {int(step): {k: d[()] for k, d in g.items()}
                      for step, g in f.get(FRAME_DATA, {}).items()}
        return ReductionPartial(_text(f.attrs["key"]) or "", steps, tables,
                                int(f.attrs.get("samples", 0)), frame_data)


def _check_versions(f: h5py.File, path: Path) -> None:
    here = software_versions()
    there = {k: _text(f.attrs.get(k)) or "unknown" for k in SOFTWARE}
    layout = (int(f.attrs.get("limb_bits", 0)), int(f.attrs.get("fraction_bits", 0)))
    if there != here or layout != (LIMB_BITS, FRACTION_BITS):
        made = ", ".join(f"{k} {v}" for k, v in there.items())
        this = ", ".join(f"{k} {v}" for k, v in here.items())
        raise PartialError(f"partial {path} was made by {made}; this is {this}: reduce those "
                           "frames again with this version (delete the partial)")


def _read_sums(group: h5py.Group) -> SparseSums:
    return SparseSums(int(group.attrs["n_bins"]), group["bins"][()], group["count"][()],
                      group["limbs"][()])


def _read_table(group: h5py.Group) -> TablePartial:
    kind = _text(group.attrs["kind"]) or ""
    grid: dict[str, Any] = {k: group[k][()] for k in group
                            if isinstance(group[k], h5py.Dataset) and k.endswith("_edges")}
    if "fold_delta_phi" in group.attrs:
        grid["fold_delta_phi"] = bool(group.attrs["fold_delta_phi"])
    budget = None
    if "budget" in group:
        b = group["budget"]
        budget = BudgetPartial(tuple(tuple(t) for t in json.loads(_text(b.attrs["independent"]) or "[]")),
                               tuple(tuple(t) for t in json.loads(_text(b.attrs["correlated"]) or "[]")),
                               _read_sums(b))
    dropped = (int(group.attrs["dropped_nan"]), int(group.attrs["dropped_range"]))
    return TablePartial(kind, _read_sums(group), dropped, grid, budget)


def _text(value: Any) -> str | None:
    if value is None:
        return None
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)
