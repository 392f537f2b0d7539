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
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from acquisition.session.engine import StepEvent
    from acquisition.session.folder import SessionFolder
    from acquisition.session.journal import StepRecord


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
