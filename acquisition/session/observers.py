"""Observers of a running session: progress, log, live reduction, user callbacks.

The engine (:class:`acquisition.session.engine.SessionEngine`) calls every observer's
:meth:`Observer.start`, then :meth:`Observer.step` after each journal step completes,
:meth:`Observer.checkpoint` at each checkpoint, and :meth:`Observer.finish` or
:meth:`Observer.error` at the end. Observers run on host time (the simulated clock is stopped)
and must not touch the devices.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acquisition.geometry.kinematics import Pose
from acquisition.session.steps import POSE, REFERENCE

if TYPE_CHECKING:
    from acquisition.session.engine import StepEvent
    from acquisition.session.folder import SessionFolder
    from acquisition.session.journal import StepRecord
    from acquisition.tables import IsotropicTable


class Observer:
    """Base class: every hook does nothing; override the ones you need."""

    def start(self, folder: SessionFolder, total: int | None, done: int) -> None:
        """The run begins with ``done`` of ``total`` journal steps already done."""

    def step(self, event: StepEvent) -> None:
        """A journal step completed."""

    def checkpoint(self, label: str, done: int) -> None:
        """The plan reached a checkpoint."""

    def finish(self, counts: dict[str, int]) -> None:
        """The plan ran to its end; ``counts`` are the journal's status counts."""

    def error(self, exc: BaseException) -> None:
        """The run stopped on ``exc`` (re-raised after the observers are told)."""


class ProgressObserver(Observer):
    """Adapts a ``callback(done, total, record)`` (e.g. a progress bar) to the observer hooks."""

    def __init__(self, callback: Callable[[int, int, StepRecord], None]) -> None:
        self.callback = callback

    def step(self, event: StepEvent) -> None:
        self.callback(event.done, event.total or event.done, event.record)


class LogObserver(Observer):
    """Writes one log line per step (INFO) and the start, end and errors of the run."""

    def __init__(self, logger: logging.Logger | None = None) -> None:
        self.log = logger or logging.getLogger("gonio.session")

    def start(self, folder: SessionFolder, total: int | None, done: int) -> None:
        self.log.info("session %s: %d of %s steps done", folder.path, done, total or "?")

    def step(self, event: StepEvent) -> None:
        r = event.record
        where = "" if r.theta_i is None else f" θi={r.theta_i:g}° θr={r.theta_r:g}° Δφ={r.delta_phi:g}°"
        self.log.info("step %d %s%s done (%d/%s)", r.step, r.kind, where, event.done,
                      event.total or "?")

    def checkpoint(self, label: str, done: int) -> None:
        self.log.debug("checkpoint %s after %d steps", label, done)

    def finish(self, counts: dict[str, int]) -> None:
        self.log.info("run finished: %s", counts)

    def error(self, exc: BaseException) -> None:
        self.log.error("run stopped: %s", exc)


class CallbackObserver(Observer):
    """Calls ``on_step(event)`` (and optionally ``on_checkpoint(label, done)``)."""

    def __init__(
        self,
        on_step: Callable[[StepEvent], None],
        on_checkpoint: Callable[[str, int], None] | None = None,
    ) -> None:
        self.on_step = on_step
        self.on_checkpoint = on_checkpoint

    def step(self, event: StepEvent) -> None:
        self.on_step(event)

    def checkpoint(self, label: str, done: int) -> None:
        if self.on_checkpoint is not None:
            self.on_checkpoint(label, done)


class LiveReduction(Observer):
    """A BRDF estimate while the capture runs.

    Each pose frame is linearized and divided by the latest white-reference frame (the final
    reduction interpolates the reference in time instead), binned into an isotropic table with
    the plan's bins. Frames taken before this observer started (a resumed run) are not seen.

    Attributes
    ----------
    table
        The running :class:`~acquisition.tables.IsotropicTable` (sr⁻¹), None before start.
    samples
        ``(pose, rgb)`` per binned frame: pose in degrees (from the read-back joints), BRDF in
        sr⁻¹.
    """

    def __init__(self) -> None:
        self.table: IsotropicTable | None = None
        self.samples: list[tuple[Pose, np.ndarray]] = []
        self._ref: np.ndarray | None = None

    def start(self, folder: SessionFolder, total: int | None, done: int) -> None:
        from acquisition.tables import IsotropicTable

        self._folder = folder
        rig, plan = folder.rig(), folder.plan()
        self._rig = rig
        self._kin = rig.kinematics()
        if self.table is None:
            t = plan.table
            self.table = IsotropicTable(t.theta_i_edges, t.theta_r_edges, t.delta_phi_edges,
                                        provenance={"live": True, "session": str(folder.path)})

    def step(self, event: StepEvent) -> None:
        from acquisition.reduction.point import frame_signal

        rec = event.record
        if event.frame is None or rec.kind not in (POSE, REFERENCE):
            return
        fs = frame_signal(event.frame, self._rig.camera.roi, rec.step)
        if fs.n_valid == 0:
            return
        if rec.kind == REFERENCE:
            self._ref = fs.signal
            return
        if self._ref is None:
            return
        pose = self._kin.forward(rec.joints_read or rec.joints_cmd)
        cos_i = np.cos(np.radians(pose.theta_i))
        if cos_i <= 0:
            return
        wr = self._rig.white_reference
        rho = np.asarray(wr.reflectance, float)
        f = fs.signal / self._ref * (rho / np.pi) * (np.cos(np.radians(wr.theta_i)) / cos_i)
        assert self.table is not None
        self.table.add(pose.theta_i, pose.theta_r, pose.delta_phi, f[None, :])
        self.samples.append((pose, f))

    def peak(self, channel: int = 1) -> Pose:
        """The measured pose (degrees) with the largest BRDF in ``channel`` (default green)."""
        if not self.samples:
            raise ValueError("no pose frame reduced yet")
        best = max(self.samples, key=lambda s: float(s[1][channel]))
        return best[0]


def frame_path(folder: SessionFolder, record: StepRecord) -> Path | None:
    """The frame file of a journal record, if it has one."""
    return None if record.frame is None else folder.frames_dir / record.frame
