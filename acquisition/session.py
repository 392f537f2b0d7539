"""Capture sessions: a folder that holds everything needed to finish, check and reduce a run.

Layout of a session folder::

    rig.toml        copy of the rig file used
    plan.toml       copy of the plan file used
    session.json    material, seed, versions (provenance)
    journal.sqlite  every step's intent and completion (see acquisition.journal)
    frames/         RAW frames, written atomically, named step-NNNNNN.dng

:func:`create_session` plans the sweep once and records every step; :class:`CaptureEngine`
runs the steps still to do, so ``gonio resume`` after Ctrl-C, a crash or a power cut continues
exactly where the run stopped.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from drivers.errors import GonioError, SafetyStop, SessionError

from .journal import Journal, StepRecord
from .kinematics import Pose
from .plan import PlanSpec, load_plan
from .planner import Planner, Sweep
from .rig import RigConfig, load_rig
from .storage import TMP_SUFFIX, atomic_target, sha256_file

RIG_FILE = "rig.toml"
PLAN_FILE = "plan.toml"
INFO_FILE = "session.json"
JOURNAL_FILE = "journal.sqlite"
FRAMES_DIR = "frames"

REFERENCE = "reference"
POSE = "pose"


class CaptureDevices(Protocol):
    """What the engine needs from an open rig (real or simulated)."""

    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        """Checked move; returns the read-back joints (degrees)."""

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> None:
        """Expose one RAW frame into ``path``."""

    def present(self, target: str) -> None:
        """Put the sample or the white reference ("sample" / "white") under the rig."""

    def stop_motion(self) -> None:
        """Stop every axis at once (goal := present), torque stays on."""

    def device_time_s(self) -> float | None:
        """The device clock (simulated rigs), or None."""

    def host_work(self) -> AbstractContextManager[None]:
        """Context for host-only work (checks, journal, hashing): a simulated rig's clock
        stops inside it, since host time is not rig time scaled up."""


@dataclass(frozen=True)
class SessionInfo:
    """Provenance of a session (``session.json``)."""

    material: str | None
    seed: int
    created_at: float
    rig_name: str
    plan_name: str
    estimated_s: float

    def to_json(self) -> dict[str, Any]:
        return self.__dict__.copy()


class SessionFolder:
    """An existing session folder (see :func:`create_session`)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        for name in (RIG_FILE, PLAN_FILE, INFO_FILE, JOURNAL_FILE):
            if not (self.path / name).is_file():
                raise SessionError(
                    f"{self.path} is not a gonio session ({name} missing): "
                    "give the folder `gonio capture --out` wrote"
                )
        self.info = SessionInfo(**json.loads((self.path / INFO_FILE).read_text()))

    @property
    def frames_dir(self) -> Path:
        return self.path / FRAMES_DIR

    def rig(self) -> RigConfig:
        return load_rig(self.path / RIG_FILE)

    def plan(self) -> PlanSpec:
        return load_plan(self.path / PLAN_FILE)

    def journal(self) -> Journal:
        return Journal(self.path / JOURNAL_FILE)


def schedule_steps(sweep: Sweep, reference_joints: dict[str, float], reference_pose: Pose,
                   reference_every: int) -> list[tuple[str, float, float, float, dict[str, float]]]:
    """Interleave white-reference steps (first, every N poses, last) with the sweep's poses."""
    ref = (REFERENCE, *reference_pose.as_tuple(), reference_joints)
    rows: list[tuple[str, float, float, float, dict[str, float]]] = [ref]
    for i, step in enumerate(sweep.steps):
        if reference_every and i and i % reference_every == 0:
            rows.append(ref)
        rows.append((POSE, *step.pose.as_tuple(), step.joints))
    rows.append(ref)
    return rows


def create_session(
    out: str | Path,
    rig_path: str | Path,
    plan_path: str | Path,
    *,
    material: str | None,
    seed: int = 0,
) -> tuple[SessionFolder, Sweep]:
    """Plan the sweep and lay out a new session folder; refuses an existing one."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SessionError(
            f"{out} already exists: choose a new --out folder, or `gonio resume {out}` to continue it"
        )
    rig = load_rig(rig_path)
    plan = load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    wr = rig.white_reference
    ref_pose = Pose(wr.theta_i, wr.theta_r, wr.delta_phi)
    ref_joints = planner.joints_for(ref_pose)
    sweep = planner.plan(plan.poses(), ref_joints)
    if not sweep.steps:
        raise SessionError(f"plan {plan_path} leaves no measurable pose on this rig: widen its ranges")
    out.mkdir(parents=True, exist_ok=True)
    try:
        (out / FRAMES_DIR).mkdir()
        shutil.copyfile(rig_path, out / RIG_FILE)
        shutil.copyfile(plan_path, out / PLAN_FILE)
        info = SessionInfo(material, seed, time.time(), rig.name, plan.name, sweep.estimated_s)
        (out / INFO_FILE).write_text(json.dumps(info.to_json(), indent=2))
        with Journal(out / JOURNAL_FILE) as journal:
            journal.plan_steps(schedule_steps(sweep, ref_joints, ref_pose, plan.capture.reference_every))
            journal.set_meta("rejected", sweep.rejected_counts())
            journal.set_meta("estimate", sweep.summary())
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    return SessionFolder(out), sweep


def frame_name(step: int) -> str:
    return f"step-{step:06d}.dng"


ProgressCallback = Callable[[int, int, StepRecord], None]
"""Called after each completed step with (done, total, record)."""


class CaptureEngine:
    """Runs a session's remaining steps on open devices.

    Parameters
    ----------
    folder:
        The session.
    devices:
        An open rig (see :mod:`acquisition.devices`).
    saturated:
        ``saturated(frame_path) -> bool``: whether the region of interest clipped; the step is
        retaken at a quarter of the exposure, up to the rig's ``max_exposure_retries``.
    """

    def __init__(
        self,
        folder: SessionFolder,
        devices: CaptureDevices,
        saturated: Callable[[Path], bool],
        progress: ProgressCallback | None = None,
    ) -> None:
        self.folder = folder
        self.devices = devices
        self.saturated = saturated
        self.progress = progress
        self.rig = folder.rig()
        self.plan = folder.plan()

    def verify_done_steps(self, journal: Journal) -> int:
        """Send back to 'planned' every done step whose frame is missing or fails its hash."""
        redo = 0
        for partial in self.folder.frames_dir.glob(f"*{TMP_SUFFIX}"):
            partial.unlink()
        for rec in journal.steps():
            if rec.status != "done":
                continue
            frame = self.folder.frames_dir / (rec.frame or "")
            if not frame.is_file():
                journal.mark_redo(rec.step, f"frame {rec.frame} missing: retaking")
                redo += 1
            elif sha256_file(frame) != rec.sha256:
                journal.mark_redo(rec.step, f"frame {rec.frame} fails its SHA-256: retaking")
                redo += 1
        return redo

    def run(self) -> dict[str, int]:
        """Capture every step not yet done; returns the journal's status counts."""
        with self.folder.journal() as journal:
            self.verify_done_steps(journal)
            records = list(journal.steps())
            total = len(records)
            done = sum(r.status == "done" for r in records)
            exposure = self.plan.capture.exposure_s or self.rig.camera.exposure_s
            iso = self.plan.capture.iso or self.rig.camera.iso
            present = None
            current: StepRecord | None = None
            try:
                for rec in records:
                    if rec.status == "done":
                        continue
                    current = rec
                    target = "white" if rec.kind == REFERENCE else "sample"
                    if target != present:
                        self.devices.present(target)
                        present = target
                    self._run_step(journal, rec, exposure, iso)
                    done += 1
                    if self.progress:
                        self.progress(done, total, rec)
            except KeyboardInterrupt:
                self.devices.stop_motion()
                where = current.step if current else None
                journal.log("warning", "interrupted by the operator", where)
                raise SafetyStop(
                    f"interrupted at step {where}: all axes stopped, torque on; "
                    f"continue with `gonio resume {self.folder.path}`"
                ) from None
            except GonioError as exc:
                journal.log("error", str(exc), current.step if current else None)
                raise
            return journal.counts()

    def _run_step(self, journal: Journal, rec: StepRecord, exposure_s: float, iso: int) -> None:
        with self.devices.host_work():
            journal.mark_started(rec.step)
        readback = self.devices.move_to(rec.joints_cmd)
        seed_base = self.folder.info.seed * 1_000_003 + rec.step * 17
        name = frame_name(rec.step)
        final = self.folder.frames_dir / name
        retries = self.rig.camera.max_exposure_retries
        for attempt in range(retries + 1):
            try:
                with atomic_target(final) as tmp:
                    self.devices.capture(tmp, exposure_s, iso, seed_base + attempt)
                    with self.devices.host_work():
                        clipped = attempt < retries and self.saturated(tmp)
                    if clipped:
                        raise _Retake()
            except _Retake:
                exposure_s /= 4.0
                continue
            break
        with self.devices.host_work():
            journal.mark_done(
                rec.step, frame=name, sha256=sha256_file(final), joints_read=readback,
                exposure_s=exposure_s, iso=iso, device_time_s=self.devices.device_time_s(),
            )


class _Retake(Exception):
    """Internal: discard the frame just written and expose again."""
