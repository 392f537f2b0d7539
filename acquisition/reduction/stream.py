"""Reduction while the capture runs: frames reduced as they land, the table the same bits.

A stream is fed the session's journal again and again (:meth:`update`, with whether the
capture still runs) and reduces what has become final since; :meth:`finish` then gives the
reduction that :func:`acquisition.reduction.point.reduce_session` gives of the same frames,
bit for bit.

* Point sessions (:class:`PointStream`): each frame's ROI signal is read as soon as the journal
  marks it done (an HDR bracket once it is complete). The table needs every white reference
  and every sample (the angular budget), so it is built at :meth:`finish`, from the signals.
* Image-based sessions (:class:`ImageStream`): a sample frame's scale C comes from the two
  white references around it (:meth:`ImageReducer.reference_at`). A frame is binned into the
  exact partial tables once both are known: every reference planned before it is done (or the
  capture ended), and the next usable one after it is done (or none will come). Frames after
  the last reference so far wait for the next one (``reference_every`` frames at most).
  The running sums are checkpointed (:mod:`acquisition.reduction.checkpoint`) every
  ``checkpoint_every`` frames and whenever the stream stops, so a stream started again after
  a crash or SIGKILL continues from there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.badframes import FrameCheck
from acquisition.reduction.checkpoint import Checkpointed, reduction_key
from acquisition.reduction.image import (
    ImageReducer,
    ImageReduction,
    sample_frames,
)
from acquisition.reduction.imageangular import ImageAngular
from acquisition.reduction.point import (
    FrameSignal,
    PointReducer,
    Reduction,
    SignalFrame,
    find_bundle,
    read_signal,
    split_samples,
)
from acquisition.session.engine import REFERENCE
from acquisition.session.folder import SessionFolder
from acquisition.session.hdr import HDR_DONE_META, hdr_group
from acquisition.session.journal import StepRecord
from calibration.bundle import CalibrationBundle
from drivers.errors import SessionError


@dataclass(frozen=True)
class JournalView:
    """What a stream needs of the journal at one moment: every row (any status), the HDR
    brackets recorded complete, and whether the capture has ended (no row will change)."""

    rows: list[StepRecord]
    complete: set[int]
    ended: bool

    @classmethod
    def read(cls, folder: SessionFolder, ended: bool) -> JournalView:
        """The journal now (read-only)."""
        with folder.journal(readonly=True) as journal:
            rows = list(journal.steps())
            groups = {g for g in (hdr_group(r.note) for r in rows) if g is not None}
            complete = {g for g in groups if journal.meta(f"{HDR_DONE_META}{g}") is not None}
        return cls(rows, complete, ended)

    @property
    def done(self) -> list[StepRecord]:
        return [r for r in self.rows if r.status == "done"]

    @property
    def pending(self) -> int:
        """Rows not done."""
        return sum(r.status != "done" for r in self.rows)

    @property
    def final(self) -> bool:
        """The capture ended with every row done: nothing more will come. (One that stopped
        early may be resumed: a reference still to come would change frames before it.)"""
        return self.ended and self.pending == 0


class PointStream:
    """A point session's frames read as they land; the table built at :meth:`finish`."""

    def __init__(self, folder: SessionFolder, bundle: str | Path | None = None) -> None:
        self.folder, self.bundle = folder, bundle
        self.rig = folder.rig()
        self.cal: CalibrationBundle | None = find_bundle(folder, bundle)
        self.check = FrameCheck(folder.path)
        self.signals: dict[int, FrameSignal] = {}
        self._tried: set[int] = set()

    @property
    def frames_reduced(self) -> int:
        return len(self.signals)

    def update(self, view: JournalView) -> int:
        """Read every frame the journal holds as done and not read yet; returns how many."""
        refs, samples = split_samples(view.done, view.complete)
        new = [f for f in [*(SignalFrame((r,)) for r in refs), *samples] if f.step not in self._tried]
        for frame in new:
            self._tried.add(frame.step)
            fs = read_signal(self.folder, self.rig, self.cal, frame, self.check)
            if fs is not None:
                self.signals[frame.step] = fs
        return len(new)

    def save(self) -> None:
        """Nothing to keep: a point stream started again reads its (small) frames again."""

    def complete(self, view: JournalView) -> None:
        """Nothing left: every frame done was read."""

    def finish(self) -> Reduction:
        """The session's reduction from the signals read (the others, if any, read now)."""
        self.check.raise_if_any()
        return PointReducer.open(self.folder, self.bundle, signals=self.signals).reduce()

    def snapshot(self) -> Reduction | None:
        """The table of the frames done so far (None before a reference and a sample)."""
        if self.check.bad or not self.signals:
            return None
        try:
            return self.finish()
        except SessionError:  # no white reference or no sample yet
            return None


@dataclass
class _References:
    """The white references read so far: C and its variance by step, and those unusable."""

    usable: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    unusable: set[int] = field(default_factory=set)

    def known(self, step: int) -> bool:
        return step in self.usable or step in self.unusable


class ImageStream:
    """An image-based session's frames binned as their white references become known."""

    def __init__(self, folder: SessionFolder, bundle: str | Path | None = None,
                 checkpoint: str | Path | None = None,
                 checkpoint_every: int = CHECKPOINT_EVERY) -> None:
        self.t0 = time.monotonic()
        self.reducer = ImageReducer.begin(folder, bundle)
        self.table, self.merl = self.reducer.tables()
        self.angular = ImageAngular(self.reducer.rig, self.reducer.model, self.table)
        self.refs = _References()
        self.run = Checkpointed("", {"isotropic": self.table, "merl": self.merl}, checkpoint,
                                checkpoint_every, inputs=(folder.path,))
        self._resumed = False
        self._tried: set[int] = set()

    @property
    def frames_reduced(self) -> int:
        return len(self.run.steps)

    def key(self, through: float) -> str:
        """The checkpoint's key: the session, calibration, options, grid and the white
        references up to journal step ``through`` (those its frames were scaled by)."""
        r = self.reducer
        steps = sorted(s for s in self.refs.usable if s <= through)
        values = np.concatenate([np.array(steps, float), *(np.concatenate(self.refs.usable[s])
                                                            for s in steps)])
        plan = r.folder.plan().table
        return reduction_key("image-stream", r.folder, r.cal, values, min_cos=r.min_cos,
                             edges=[list(map(float, e)) for e in (
                                 plan.theta_i_edges, plan.theta_r_edges, plan.delta_phi_edges)])

    def update(self, view: JournalView, final: bool | None = None) -> int:
        """Read the white references done since, then bin every frame whose references are
        known; returns how many frames were binned. ``final`` (default ``view.final``): take
        the references done as all there will be (``gonio reduce`` of a session as it is)."""
        for rec in (r for r in view.done if r.kind == REFERENCE and not self.refs.known(r.step)):
            got = self.reducer.read_reference(rec)
            if got is None:
                self.refs.unusable.add(rec.step)
            else:
                self.refs.usable[rec.step] = got
        if not self._resumed and (self.refs.usable or view.ended):
            self._resume(view)  # the references known, a checkpoint can be checked
        if not self.refs.usable:
            return 0
        self.reducer.set_references((s, *v) for s, v in self.refs.usable.items())
        planned = sorted(r.step for r in view.rows if r.kind == REFERENCE)
        ready = [f for f in sample_frames(view.done, view.complete)
                 if f[0].step not in self.run.steps and f[0].step not in self._tried
                 and self._final(f[0].step, planned, view.final if final is None else final)]
        self._tried.update(f[0].step for f in ready)  # a frame that cannot be read: once
        self.run.key = self.key(self._last_reference)  # what the checkpoints save
        for step, count, arrays in self.reducer.reduce(ready, self.table, self.merl,
                                                       self.angular):
            self.run.frame_done(step, count, arrays)
        return len(ready)

    @property
    def _last_reference(self) -> float:
        return float(max(self.refs.usable))

    def _final(self, step: int, planned: list[int], final: bool) -> bool:
        """Whether the references that scale the frame at ``step`` are all known."""
        if final:
            return True
        if any(not self.refs.known(s) for s in planned if s < step):
            return False
        for s in (s for s in planned if s > step):
            if not self.refs.known(s):
                return False
            if s in self.refs.usable:
                return True
        return False  # no usable reference after it yet: one may still come

    def _resume(self, view: JournalView) -> None:
        """Take a checkpoint whose key matches the references up to one of the known ones."""
        self._resumed = True
        frames = {f[0].step for f in sample_frames(view.done, view.complete)}
        for through in sorted(self.refs.usable, reverse=True):
            self.run.key = self.key(through)
            if self.run.resume(frames):
                return
        self.run.key = ""

    def save(self) -> None:
        """Write the checkpoint now (when frames were binned)."""
        if self.run.steps:
            self.run.key = self.key(self._last_reference)
            self.run.save()

    def complete(self, view: JournalView) -> None:
        """Bin the frames left, taking the references done as all there are (the table of a
        capture that stopped early, as ``gonio reduce`` makes it). The checkpoint is no longer
        written: it keeps only frames a resumed capture cannot change."""
        self.run.every = 0
        self.update(view, final=True)

    def snapshot(self) -> ImageReduction | None:
        """The tables of the frames binned so far (None before the first), finished on copies:
        the running sums go on."""
        if not self.run.steps:
            return None
        table, merl = self.reducer.tables()
        done = self.run.partial()
        table.merge_partial(done.tables["isotropic"])
        merl.merge_partial(done.tables["merl"])
        return self.reducer.finish(table, merl, done, self.t0, resumed=self.run.resumed)

    def finish(self) -> ImageReduction:
        """The reduction of every frame binned (after the last :meth:`update`, or
        :meth:`complete`)."""
        self.reducer.check.raise_if_any()
        if not self.refs.usable:
            ImageReducer.open(self.reducer.folder, self.reducer.cal)  # its one-line error
        return self.reducer.finish(self.table, self.merl, self.run.partial(), self.t0,
                                   resumed=self.run.resumed)


def open_stream(folder: SessionFolder, bundle: str | Path | None = None,
                checkpoint: str | Path | None = None,
                checkpoint_every: int = CHECKPOINT_EVERY) -> PointStream | ImageStream:
    """The stream for the session's kind of rig."""
    if folder.rig().sample.image_based:
        return ImageStream(folder, bundle, checkpoint, checkpoint_every)
    return PointStream(folder, bundle)


def follow(folder: SessionFolder, stream: PointStream | ImageStream,
           running: Callable[[], bool], poll_s: float = 0.2,
           progress: Callable[[int, int], None] | None = None,
           each_round: Callable[[JournalView], None] | None = None) -> JournalView:
    """Feed ``stream`` the journal every ``poll_s`` host seconds until ``running()`` turns
    False, then once more (the capture has ended); returns that last view.
    ``progress(frames reduced, journal rows)`` and ``each_round(view)`` after each round but
    the last."""
    while True:
        ended = not running()  # asked before reading: the last read sees every row
        view = JournalView.read(folder, ended)
        stream.update(view)
        if progress:
            progress(stream.frames_reduced, len(view.rows))
        if ended:
            return view
        if each_round:
            each_round(view)
        time.sleep(poll_s)
