"""Checkpoints: a reduction's partial tables saved as it goes, so an interrupted reduction
resumes where it stopped.

An image-based reduction (:func:`acquisition.reduction.image.reduce_image_session`) given a
checkpoint file saves the exact sums of the frames binned so far
(:mod:`acquisition.tables.partial`, atomically: never a half-written file) every
:data:`CHECKPOINT_EVERY` frames and once every frame is binned. Run again after a crash or
SIGKILL, it takes those frames from the file and reduces only the others; the sums are exact,
so the table is the one an uninterrupted run gives, byte for byte.

The file lives beside the output table, ``NAME.checkpoint.h5`` for ``NAME.h5``
(:func:`checkpoint_path`): the output's folder is writable, the session's need not be.
``gonio reduce`` deletes it once the table is written. A checkpoint of another reduction (other
session, calibration bundle, options, or white-reference frames added by a resumed capture) is
not used: the reduction starts over and replaces it. One written by another gonio, numpy or
numba version is refused in one line naming both (delete it to start over).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from contextlib import suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.session.folder import SessionFolder
from acquisition.tables.partial import ReductionPartial, TablePartial, load_partial, save_partial
from calibration.bundle import CalibrationBundle

if TYPE_CHECKING:
    from acquisition.reduction.point import Reduction

SUFFIX = ".checkpoint.h5"


class PartialTable(Protocol):
    def partial(self) -> TablePartial: ...

    def merge_partial(self, part: TablePartial) -> None: ...


def checkpoint_path(table_path: str | os.PathLike[str]) -> Path:
    """Where the reduction into ``table_path`` keeps its checkpoint: beside it."""
    path = Path(table_path)
    return path.with_name(path.stem + SUFFIX)


def reduction_key(kind: str, folder: SessionFolder, cal: CalibrationBundle | None,
                  references: np.ndarray, **options: Any) -> str:
    """A digest of what a reduction's partials depend on: the session, the calibration bundle,
    the reference values (``references``) and ``options`` (JSON-serialisable)."""
    refs = hashlib.sha256(np.ascontiguousarray(references, np.float64).tobytes()).hexdigest()
    text = json.dumps({"kind": kind, "session": str(folder.path.resolve()),
                       "calibration": None if cal is None else str(cal.path.resolve()),
                       "references": refs, **options}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


class Checkpointed:
    """The running tables of one reduction (``tables``: name → table with ``partial()`` and
    ``merge_partial()``), the frames (journal steps) in them, and their checkpoint file (None:
    no checkpoint)."""

    def __init__(self, key: str, tables: Mapping[str, PartialTable],
                 path: str | os.PathLike[str] | None, every: int = CHECKPOINT_EVERY,
                 inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
        self.key = key
        self.tables = dict(tables)
        self.path = None if path is None else Path(path)
        self.every = int(every)
        self.inputs = tuple(inputs)
        self.steps: set[int] = set()
        self.frame_data: dict[int, Mapping[str, np.ndarray]] = {}
        self.samples = 0
        self.resumed = 0
        self._since = 0

    def resume(self, steps: Iterable[int]) -> set[int]:
        """Merge the checkpoint's tables in when it belongs to this reduction and holds only
        frames among ``steps``; returns the steps it holds (empty: start from the first)."""
        if self.path is None or not self.path.exists():
            return set()
        part = load_partial(self.path)  # refused when made by other versions
        if part.key != self.key or not part.steps <= set(steps) or set(part.tables) != set(self.tables):
            return set()
        for name, table in self.tables.items():
            table.merge_partial(part.tables[name])
        self.steps = set(part.steps)
        self.frame_data = dict(part.frame_data)
        self.samples = part.samples
        self.resumed = len(part.steps)
        return set(part.steps)

    def frame_done(self, step: int, samples: int,
                   data: Mapping[str, np.ndarray] | None = None) -> None:
        """One more frame binned (its first journal step, its samples, the arrays the
        reduction needs of it at the end); saves every ``every`` frames."""
        self.steps.add(int(step))
        if data is not None:
            self.frame_data[int(step)] = data
        self.samples += int(samples)
        self._since += 1
        if self.every > 0 and self._since >= self.every:
            self.save()

    def partial(self) -> ReductionPartial:
        """The partial tables of every frame binned so far."""
        return ReductionPartial(self.key, frozenset(self.steps),
                                {name: t.partial() for name, t in self.tables.items()},
                                self.samples, dict(self.frame_data))

    def save(self) -> None:
        """Write the checkpoint now (atomically)."""
        self._since = 0
        if self.path is not None:
            save_partial(self.path, self.partial(), self.inputs)


def write_table(result: Reduction, out: str | Path, session: str | Path, *,
                keep_checkpoint: bool = False) -> None:
    """Save a reduction's table (and an image-based session's MERL table in it) at ``out``
    atomically, then delete the checkpoint beside it: the table supersedes it (unless
    ``keep_checkpoint``: the table of a capture that will be resumed)."""
    result.table.save_h5(out, inputs=(session,), merl=getattr(result, "merl", None))
    if not keep_checkpoint:
        with suppress(FileNotFoundError):
            checkpoint_path(out).unlink()
