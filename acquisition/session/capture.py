"""Pre-planned captures (``gonio capture`` / ``gonio resume``): the journal's rows replayed as
step records by a :class:`~acquisition.session.engine.SessionEngine`."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from acquisition.session.engine import CaptureDevices, ProgressCallback, SessionEngine
from acquisition.session.folder import SessionFolder
from acquisition.session.hdr import HDR_SWEEP_META
from acquisition.session.journal import Journal, StepRecord
from acquisition.session.steps import (
    POSE,
    REFERENCE,
    Checkpoint,
    Expose,
    ExposeHDR,
    Move,
    Reference,
    Step,
    capture_steps,
)
from drivers.errors import (
    SessionError,
)

if TYPE_CHECKING:
    from acquisition.session.observers import Observer


def steps_from_journal(records: Iterable[StepRecord]) -> Iterator[Step]:
    """Replay a pre-planned session (``gonio capture``): its journal rows as step records."""
    for rec in records:
        pose = None if rec.theta_i is None else Pose(rec.theta_i, rec.theta_r, rec.delta_phi)
        if rec.kind == REFERENCE:
            yield Reference(pose, rec.joints_cmd)
        elif rec.kind == POSE:
            assert pose is not None
            yield Move(pose, rec.joints_cmd)
            yield Expose()
        else:
            raise SessionError(
                f"journal step {rec.step} is a '{rec.kind}' step of a scripted session: "
                "rerun its script to continue it"
            )
        yield Checkpoint()


class CaptureEngine:
    """Runs a pre-planned session's remaining steps (``gonio capture`` / ``gonio resume``).

    A thin wrapper: the journal's rows become step records (:func:`steps_from_journal`)
    run by a :class:`SessionEngine` with a progress observer.
    """

    def __init__(
        self,
        folder: SessionFolder,
        devices: CaptureDevices,
        saturated: Callable[[Path], bool],
        progress: ProgressCallback | None = None,
        observers: Sequence[Observer] = (),
        planner: Planner | None = None,
    ) -> None:
        from acquisition.session.observers import ProgressObserver

        obs = list(observers)
        if progress is not None:
            obs.append(ProgressObserver(progress))
        self.engine = SessionEngine(folder, devices, planner or folder.planner(),
                                    saturated=saturated, observers=obs)
        self.folder = folder

    def verify_done_steps(self, journal: Journal) -> int:
        return self.engine.verify_done_steps(journal)

    def run(self) -> dict[str, int]:
        """Capture every step not yet done; returns the journal's status counts."""
        if self.folder.info.scripted:
            raise SessionError(
                f"{self.folder.path} is a scripted session: rerun its script to continue it"
            )
        with self.folder.journal() as journal:
            records = list(journal.steps())
            hdr_sweep = journal.meta(HDR_SWEEP_META)
        if hdr_sweep is not None:
            eng = self.engine
            every = eng.plan.capture.reference_every
            poses = [(Pose(ti, tr, dp), joints) for ti, tr, dp, joints in hdr_sweep]
            refs = 2 + ((len(poses) - 1) // every if every else 0)
            steps = capture_steps(poses, reference_every=every,
                                  reference=Reference(eng.ref_pose, eng.ref_joints),
                                  expose=ExposeHDR())
            return eng.run(steps, total=len(poses) + refs)  # a lower bound: ≥ 1 frame per pose
        return self.engine.run(steps_from_journal(records))
