"""Capture sessions: a folder that holds everything needed to finish, check and reduce a run.

Layout of a session folder (see docs/formats.md)::

    rig.toml        copy of the rig file used
    plan.toml       copy of the plan file used
    calibration/    copy of the calibration used, when one was given
    session.json    material, seed, versions (provenance)
    journal.sqlite  every step's intent and completion (see acquisition.session.journal)
    frames/         RAW frames, written atomically, named step-NNNNNN.dng

:func:`create_session` lays the folder out (for ``gonio capture`` it records every planned step
in the journal); :class:`SessionFolder` opens an existing one.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from acquisition.config.plan import PlanSpec, load_plan
from acquisition.config.rig import RigConfig, load_rig
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner, Sweep
from acquisition.session.alignment import alignment_of, bundle_at
from acquisition.session.hdr import HDR_SWEEP_META
from acquisition.session.journal import Journal
from acquisition.session.steps import (
    POSE,
    REFERENCE,
    Expose,
    Move,
    Reference,
    sweep_steps,
)
from drivers.errors import SessionError, StorageError
from drivers.storage import copy_file, ensure_folder, storage_error, write_blocker, write_text

RIG_FILE = "rig.toml"


PLAN_FILE = "plan.toml"


INFO_FILE = "session.json"


JOURNAL_FILE = "journal.sqlite"


FRAMES_DIR = "frames"


CALIBRATION_DIR = "calibration"


@dataclass(frozen=True)
class SessionInfo:
    """Provenance of a session (``session.json``)."""

    material: str | None
    seed: int
    created_at: float
    rig_name: str
    plan_name: str
    estimated_s: float
    calibration: str | None = None
    """Path of the copied calibration inside the session folder, if any."""
    scripted: bool = False
    """True when a script's step plan (not the plan file's sweep) drives the session."""

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
        self._rig: RigConfig | None = None
        self._plan: PlanSpec | None = None
        self._planner: Planner | None = None

    @property
    def frames_dir(self) -> Path:
        return self.path / FRAMES_DIR

    def rig(self) -> RigConfig:
        """The session's rig, loaded once per folder object (its copy, unless the folder was
        just created from already loaded files)."""
        if self._rig is None:
            self._rig = load_rig(self.path / RIG_FILE)
        return self._rig

    def plan(self) -> PlanSpec:
        """The session's plan, loaded once per folder object."""
        if self._plan is None:
            self._plan = load_plan(self.path / PLAN_FILE)
        return self._plan

    def journal(self, *, readonly: bool = False) -> Journal:
        """The journal; ``readonly`` never writes into the folder (inspection, reduction)."""
        return Journal(self.path / JOURNAL_FILE, readonly=readonly)

    def require_writable(self) -> None:
        """Refuse in one line, before anything runs, to resume a session whose folder is
        read-only (resuming writes new frames and journal rows)."""
        for where in (self.path, self.frames_dir, self.path / JOURNAL_FILE):
            code = write_blocker(where) if where.exists() else None
            if code is not None:
                cause = "on a read-only filesystem" if code == errno.EROFS else "not writable by you"
                raise StorageError(
                    f"session {self.path} is {cause} ({where}): resuming needs write access to "
                    "record new frames and journal steps; remount it read-write or "
                    "copy the folder to a writable disk and resume the copy (`gonio info` and "
                    "`gonio reduce -o PATH` work as it is)")

    def write_info(self, info: SessionInfo) -> None:
        """Replace ``session.json`` (atomically)."""
        write_text(self.path / INFO_FILE, json.dumps(info.to_json(), indent=2), what="session file",
                   ours=True, own_session=True, verify=_json_file)
        self.info = info

    def planner(self) -> Planner:
        """The planner for the session's rig and plan (and the geometric calibration of its
        copied calibration bundle, if any), built once per folder object."""
        if self._planner is None:
            rig = self.rig()
            self._planner = Planner.for_plan(rig, self.plan(),
                                             alignment_of(bundle_at(self.calibration), rig))
        return self._planner

    def adopt(self, rig: RigConfig, plan: PlanSpec, planner: Planner | None = None) -> SessionFolder:
        """Use already loaded rig and plan objects (the files the session copied) and their
        planner, so a run loads and plans once; returns the folder."""
        self._rig, self._plan, self._planner = rig, plan, planner
        return self

    @property
    def calibration(self) -> Path | None:
        """The copied calibration (file or folder), if the session has one."""
        return None if self.info.calibration is None else self.path / self.info.calibration


def reference_geometry(rig: RigConfig, planner: Planner) -> tuple[Pose, dict[str, float]]:
    """The white reference's pose (deg) and joints (deg) from the rig file."""
    wr = rig.white_reference
    pose = Pose(wr.theta_i, wr.theta_r, wr.delta_phi)
    return pose, dict(planner.joints_for(pose))


def schedule_steps(sweep: Sweep, reference_joints: dict[str, float], reference_pose: Pose,
                   reference_every: int) -> list[tuple[str, float, float, float, dict[str, float]]]:
    """Journal rows (kind, θi, θr, Δφ, joints) of :func:`acquisition.session.steps.sweep_steps`."""
    ref = Reference(reference_pose, reference_joints)
    rows: list[tuple[str, float, float, float, dict[str, float]]] = []
    current: Move | None = None
    for step in sweep_steps(sweep, reference_every=reference_every, reference=ref):
        if isinstance(step, Reference):
            rows.append((REFERENCE, *reference_pose.as_tuple(), dict(reference_joints)))
        elif isinstance(step, Move):
            current = step
        elif isinstance(step, Expose):
            assert current is not None and current.joints is not None
            rows.extend([(POSE, *current.pose.as_tuple(), dict(current.joints))] * len(step.bracket))
    return rows


def _json_file(path: Path) -> None:
    json.loads(path.read_text())


def copy_calibration(source: str | Path, out: Path) -> str:
    """Copy a calibration file or folder into ``out/calibration``; returns its relative path."""
    source = Path(source)
    dest = out / CALIBRATION_DIR
    if source.is_dir():
        for folder, _, files in os.walk(source):
            target = dest / Path(folder).relative_to(source)
            ensure_folder(target, what="session folder", own_session=True, retry=_NEW)
            for name in files:
                copy_file(Path(folder) / name, target / name, what="calibration copy",
                          own_session=True, retry=_NEW)
        return CALIBRATION_DIR
    if not source.is_file():
        raise SessionError(f"calibration {source} does not exist: give a calibration file or folder")
    ensure_folder(dest, what="session folder", own_session=True, retry=_NEW)
    copy_file(source, dest / source.name, what="calibration copy", own_session=True, retry=_NEW)
    return f"{CALIBRATION_DIR}/{source.name}"


_NEW = " or choose another --out"
"""The fix's second half when a new session cannot be written."""


def _refuse_inside(out: Path, calibration: str | Path | None) -> None:
    if calibration is not None and Path(calibration).is_dir() and \
            Path(os.path.realpath(out)).is_relative_to(os.path.realpath(calibration)):
        raise SessionError(f"--out {out} lies inside the calibration folder {calibration}, which "
                           "the session copies: choose a folder outside it")


def create_session(
    out: str | Path,
    rig: RigConfig | str | Path,
    plan: PlanSpec | str | Path,
    *,
    material: str | None,
    seed: int = 0,
    calibration: str | Path | None = None,
    scripted: bool = False,
    planner: Planner | None = None,
) -> tuple[SessionFolder, Sweep | None]:
    """Lay out a new session folder; refuses an existing one.

    ``rig`` and ``plan`` are loaded configs (their files are copied) or paths; ``planner``
    (built from them when not given) plans the sweep, and the returned folder keeps all
    three, so a run loads and plans once. Unless ``scripted``, the plan file's sweep is
    planned and every step recorded in the journal now; a scripted session's steps are
    journaled as its script reaches them. With ``[capture] hdr = true`` the planned poses go
    to the journal's meta instead and each bracket's frames are journaled as they are taken.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SessionError(
            f"{out} already exists: choose a new --out folder, or `gonio resume {out}` to continue it"
        )
    rig = rig if isinstance(rig, RigConfig) else load_rig(rig)
    plan = plan if isinstance(plan, PlanSpec) else load_plan(plan)
    planner = planner or Planner.for_plan(rig, plan, alignment_of(bundle_at(calibration), rig))
    ref_pose, ref_joints = reference_geometry(rig, planner)
    sweep = None if scripted else planner.plan(plan.poses(), ref_joints)
    hdr = sweep is not None and plan.capture.hdr
    if sweep is not None and not sweep.steps:
        raise SessionError(f"plan {plan.path} leaves no measurable pose on this rig: widen its ranges")
    _refuse_inside(out, calibration)
    existed = out.exists()
    ensure_folder(out, what="session folder", retry=_NEW)
    try:
        ensure_folder(out / FRAMES_DIR, what="session folder", own_session=True, retry=_NEW)
        copy_file(rig.path, out / RIG_FILE, what="rig copy", own_session=True, retry=_NEW)
        copy_file(plan.path, out / PLAN_FILE, what="plan copy", own_session=True, retry=_NEW)
        cal = None if calibration is None else copy_calibration(calibration, out)
        info = SessionInfo(material, seed, time.time(), rig.name, plan.name,
                           sweep.estimated_s if sweep else 0.0, cal, scripted)
        write_text(out / INFO_FILE, json.dumps(info.to_json(), indent=2), what="session file",
                   own_session=True, retry=_NEW, verify=_json_file)
        with Journal(out / JOURNAL_FILE, retry=_NEW) as journal:
            if hdr and sweep is not None:  # frames per pose known only once bracketed
                journal.set_meta(HDR_SWEEP_META, [[*p.pose.as_tuple(), dict(p.joints)]
                                                  for p in sweep.steps])
            elif sweep is not None:
                journal.plan_steps(
                    schedule_steps(sweep, ref_joints, ref_pose, plan.capture.reference_every)
                )
                journal.set_meta("rejected", sweep.rejected_counts())
                journal.set_meta("estimate", sweep.summary())
    except BaseException as exc:
        if existed:  # an empty folder the operator made: leave it empty
            for child in out.iterdir():
                shutil.rmtree(child) if child.is_dir() else child.unlink()
        else:
            shutil.rmtree(out, ignore_errors=True)
        if isinstance(exc, OSError) and not isinstance(exc, StorageError):
            raise storage_error(exc, out, "session folder", _NEW) from None
        raise
    return SessionFolder(out).adopt(rig, plan, planner), sweep


def frame_name(step: int) -> str:
    return f"step-{step:06d}.dng"
