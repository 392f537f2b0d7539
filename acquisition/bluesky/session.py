"""A brdf_sweep's session: gonio's own session engine journals every frame, one step at a time
as the bluesky devices ask for it.

Staging a :class:`SweepSession` makes the session folder (as ``gonio capture`` does: rig and
plan copies, ``session.json``, every planned step in the journal) or reopens one that a sweep
left unfinished. From then on a :class:`SweepEngine` runs on the rig's thread over the
journal's rows (:func:`~acquisition.session.capture.steps_from_journal`, as ``gonio resume``
does), but each row not done waits for the devices: a pose ``set`` becomes a :class:`GoTo`
step (the engine's own guarded, routed move, so it knows where the arms stand and does not move
them again), and a camera trigger releases the row's ``Reference`` or ``Move`` + ``Expose``
records (the engine claims the row, checks it against the journal, presents the white
reference or the sample, shoots, retakes a clipped frame, hashes and journals it). The frames,
their names, hashes and journal rows are therefore exactly those ``gonio capture`` writes.

Unstaging ends the run: with every row done the engine ends it as usual; before that it stops
at a checkpoint (journaled; ``gonio resume`` or another brdf_sweep on the folder continues).
An engine run that an error ended (a refused move, a stop from the RunEngine during a move)
starts again, from the journal, on the next request.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ophyd_async.core import AsyncStatus, Device, completed_status

from acquisition.api.sessions import keeping_run_health
from acquisition.bluesky.frames import Shot
from acquisition.bluesky.link import RigLink
from acquisition.bluesky.sweepfolder import open_sweep_folder
from acquisition.bluesky.worker import Job
from acquisition.geometry.kinematics import Pose
from acquisition.session.capture import steps_from_journal
from acquisition.session.engine import SessionEngine, StepEvent
from acquisition.session.journal import StepRecord
from acquisition.session.observers import CallbackObserver, LogObserver
from acquisition.session.steps import Checkpoint, Step
from drivers.errors import GonioError, SafetyStop, SessionError

log = logging.getLogger("gonio.bluesky")

GOTO, SHOOT, END = "goto", "shoot", "end"


@dataclass(frozen=True)
class GoTo:
    """Step record: move to ``joints`` (deg), guarded and routed (the engine skips the move
    when the arms already stand there)."""

    joints: Mapping[str, float]


class SweepEngine(SessionEngine):
    """A :class:`SessionEngine` that also runs :class:`GoTo` records and says where it stands."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.handlers[GoTo] = self._goto  # type: ignore[assignment]
        self.moving = False
        """A move is under way (the RunEngine's stop may end it); False while a frame is shot,
        so a pause then sends nothing to the servos."""

    def _goto(self, step: GoTo) -> None:
        self._go(dict(step.joints), None)

    def _go(self, joints: dict[str, float], target: str | None) -> None:
        self.moving = self._at != joints
        try:
            super()._go(joints, target)
        finally:
            self.moving = False

    def readback(self) -> dict[str, float]:
        """The read-back joints (deg) of the engine's last move."""
        return dict(self._readback)

    def forget_position(self) -> None:
        """Something else moved the arms: the next step moves them even to the same joints."""
        self._at = None

    def is_done(self, step: int) -> bool:
        """Whether the running journal holds ``step`` as done."""
        assert self._journal is not None
        rec = self._journal.record(step)
        return rec is not None and rec.status == "done"


class SweepRequest(Job):
    """What a device asks of the sweep's engine (:data:`GOTO`, :data:`SHOOT`, :data:`END`);
    its future gets the read-back joints, the :class:`Shot`, or None."""

    def __init__(self, sweep: SweepSession, kind: str, pose: Pose | None = None,
                 joints: Mapping[str, float] | None = None) -> None:
        super().__init__(sweep.serve, self)
        self.sweep = sweep
        self.kind = kind
        self.pose = pose
        self.joints = None if joints is None else dict(joints)

    def run(self) -> None:
        """From the worker's own loop: (re)start the engine with this request first."""
        if self.future.set_running_or_notify_cancel():
            self.sweep.serve(self)


class SweepSession(Device):
    """The session folder a :func:`~acquisition.bluesky.brdf_sweep` writes, as a device: stage it
    to make (or reopen) the folder and let the camera and the pose go through its engine,
    unstage it to end the run. :attr:`rows` are the journal rows still to shoot, in order."""

    def __init__(self, link: RigLink, plan_path: str | Path, session_dir: str | Path,
                 name: str = "session") -> None:
        self._link = link
        self.plan_path = Path(plan_path).absolute()
        self.session_dir = Path(session_dir).absolute()
        self.rows: list[StepRecord] = []
        """The journal rows still to shoot, in order (known once staged)."""
        self.planned = 0
        """Every journal row of the session (known once staged)."""
        self._records: list[StepRecord] = []
        self._engine: SweepEngine | None = None
        self._current: SweepRequest | None = None
        self._end: SweepRequest | None = None
        self._last: StepEvent | None = None
        super().__init__(name=name)

    @property
    def moving(self) -> bool:
        """The session engine is moving the arms."""
        return self._engine is not None and self._engine.moving

    @property
    def engine(self) -> SweepEngine:
        if self._engine is None:
            raise SessionError(f"{self.session_dir}: the sweep's session is not staged")
        return self._engine

    # ------------------------------------------------------------------ device verbs
    @AsyncStatus.wrap
    async def stage(self) -> None:
        """Make or reopen the session folder; the devices then shoot through its engine."""
        if self._link.sweep is not None:
            raise SessionError(f"a brdf_sweep into {self._link.sweep.session_dir} is running on "
                               "this rig: let it end first")
        self.rows = await self._link.worker.call(self._prepare)
        self._link.sweep = self

    def unstage(self) -> AsyncStatus:
        """End the engine's run (stopping at a checkpoint if rows are left); idempotent."""
        if self._link.sweep is not self:
            return completed_status()
        self._link.sweep = None
        return AsyncStatus(_awaited(asyncio.wrap_future(self._link.worker.put(SweepRequest(self, END)))))

    async def goto(self, pose: Pose, joints: Mapping[str, float] | None) -> dict[str, float]:
        """Move through the engine to ``joints`` (or the pose's nearest joints); read-back."""
        request = SweepRequest(self, GOTO, pose, joints)
        return await asyncio.wrap_future(self._link.worker.put(request))

    async def shoot(self) -> Shot:
        """Shoot the next journal row still to do (moving there first if the arms are not)."""
        return await asyncio.wrap_future(self._link.worker.put(SweepRequest(self, SHOOT)))

    # ------------------------------------------------------------------ rig's thread
    def _prepare(self) -> list[StepRecord]:
        devices = self._link.servo
        folder = open_sweep_folder(self._link, self.plan_path, self.session_dir)
        self._engine = SweepEngine(
            folder, devices, folder.planner(), saturated=devices.roi_saturated,
            observers=[CallbackObserver(self._stepped), LogObserver(log)])
        with folder.journal() as journal:
            self._engine.verify_done_steps(journal)
            self._records = list(journal.steps())
        self.planned = len(self._records)
        return [r for r in self._records if r.status != "done"]

    def _stepped(self, event: StepEvent) -> None:
        self._last = event

    def serve(self, first: SweepRequest) -> None:
        """Run the engine over the journal, serving requests (``first`` first) until the end."""
        if first.kind == END:  # no engine runs: nothing to end
            first.future.set_result(None)
            return
        self._current = self._end = None
        engine = self.engine
        try:
            with _guarded_by(self._link, engine.planner), \
                    keeping_run_health(engine.folder, self._link.servo):
                engine.run(self._steps(first))
        except GonioError as exc:
            if not (isinstance(exc, SafetyStop) and self._end is not None):
                self._fail(exc)
        except BaseException as exc:
            self._fail(exc)
            raise
        finally:
            if self._current is not None:
                self._fail(SessionError(f"{engine.folder.path}: the session engine stopped; "
                                        "continue the sweep or `gonio resume` the folder"))
            if self._end is not None:
                self._end.future.set_result(None)

    def _fail(self, exc: BaseException) -> None:
        request, self._current = self._current or self._end, None
        if request is self._end:
            self._end = None
        if request is not None and not request.future.done():
            request.future.set_exception(exc)
        else:
            log.error("brdf_sweep session %s: %s", self.session_dir, exc)

    def _steps(self, first: SweepRequest) -> Iterator[Step]:
        """The journal's rows as step records; a row not done waits for the camera."""
        pending = [first]
        for rec in self._records:
            row = list(steps_from_journal([rec]))
            if self.engine.is_done(rec.step):
                yield from row
                continue
            yield from self._serve_row(pending, rec, row)
            if self._end is not None:
                return
        yield from self._serve_row(pending, None, [])

    def _serve_row(self, pending: list[SweepRequest], rec: StepRecord | None,
                   row: list[Step]) -> Iterator[Step]:
        """Serve moves until the camera asks for ``rec``'s frame (None: after the last row,
        until the run ends)."""
        while True:
            request = self._next_request(pending)
            if request.kind == END:
                self._end = request
                if rec is not None:  # rows left: stop at a checkpoint, as gonio's Ctrl-C does
                    self.engine.request_stop()
                    yield Checkpoint("(the bluesky run ended)")
                return
            self._current = request
            if request.kind == GOTO:
                yield from self._goto(request)
            elif rec is None:
                request.future.set_exception(SessionError(
                    f"{self.engine.folder.path}: every frame of the session is taken"))
            else:
                yield from row
                assert self._last is not None and self._last.record.step == rec.step
                request.future.set_result(Shot.from_event(self._last))
                self._current = None
                return
            self._current = None

    def _goto(self, request: SweepRequest) -> Iterator[Step]:
        engine = self.engine
        try:
            joints = request.joints or engine.planner.joints_for(
                request.pose, self._link.servo.motion.where_deg())  # type: ignore[arg-type]
        except GonioError as exc:  # an unreachable pose: refused before anything moves
            request.future.set_exception(exc)
            return
        yield GoTo(joints)
        request.future.set_result(engine.readback())

    def _next_request(self, pending: list[SweepRequest]) -> SweepRequest:
        """The next request for this sweep (``pending``'s first); other jobs run meanwhile, in
        the order they arrive."""
        while not pending:
            job = self._link.worker.take()
            if job is None:  # the rig is closing
                self._link.worker.closing()
                return SweepRequest(self, END)
            if not isinstance(job, SweepRequest):
                job.run()
                if job.moves:
                    self.engine.forget_position()
            elif not job.future.set_running_or_notify_cancel():
                continue
            elif job.sweep is not self:
                job.future.set_exception(SessionError(
                    f"a brdf_sweep into {self.session_dir} is running on this rig"))
            else:
                return job
        return pending.pop()


async def _awaited(future: asyncio.Future[Any]) -> None:
    await future


@contextmanager
def _guarded_by(link: RigLink, planner: Any) -> Iterator[None]:
    """Guard and route every move with the session's planner (the plan's constraints) while
    its engine runs, as ``gonio capture`` does."""
    servo = link.servo
    saved = servo.planner, servo.motion.guard
    servo.planner = servo.motion.guard = planner
    try:
        yield
    finally:
        servo.planner, servo.motion.guard = saved
