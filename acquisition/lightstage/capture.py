"""Light-stage capture into a durable session folder, and resuming it.

The session folder is the one ``gonio capture`` writes (:mod:`acquisition.session.engine`): rig and
plan copies, ``session.json``, the SQLite journal and ``frames/step-NNNNNN.dng``. The plan file
only gives the table bins and capture settings (a default one is written when none is given);
the steps come from :func:`acquisition.lightstage.sequences.capture_steps`, whose arguments are
stored in the journal's ``lightstage`` meta entry so that :func:`resume_lightstage` replays
exactly the same sequence and skips what is done.
"""

from __future__ import annotations

import dataclasses
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from acquisition.config.rig import load_rig
from acquisition.config.stage import StageConfig, stage_config
from acquisition.devices.rig import OperatorPrompt, require_operator
from acquisition.lightstage.devices import LightStageDevices, open_lightstage
from acquisition.lightstage.sequences import (
    LightFrame,
    TimeEstimate,
    capture_steps,
    estimate_s,
    frame_times_s,
)
from acquisition.planning.planner import Planner
from acquisition.session.engine import SessionEngine
from acquisition.session.folder import SessionFolder, create_session
from acquisition.session.journal import StepRecord
from acquisition.session.observers import Observer, ProgressObserver
from acquisition.session.runlock import capture_lock
from acquisition.session.status import LIGHTSTAGE_META as META_KEY
from acquisition.session.status import PLANNED_STEPS_META
from acquisition.session.steps import Step
from acquisition.simworld.materials import DEFAULT_MATERIAL, parse_material
from drivers.errors import SessionError

DEFAULT_PLAN = """\
# Light-stage session settings (written by gonio lightstage capture): table bins and exposure.
# The frames themselves come from the light-stage sequence, not from these poses.
format_version = 1
name = "lightstage"
[sampling]
kind = "list"
reciprocal = "both"
bin_deg = 5
poses = [[0, 0, 0]]
"""

Progress = Callable[[int, int, StepRecord], None]
OnOpen = Callable[[SessionFolder, float | None], None]
"""Called once the devices are open: ``(session folder, device time s or None)``."""


class LightStageEngine(SessionEngine):
    """A :class:`SessionEngine` that also runs :class:`LightFrame` records on a light stage."""

    def __init__(self, folder: SessionFolder, devices: LightStageDevices, planner: Planner,
                 observers: Sequence[Observer] = ()) -> None:
        super().__init__(folder, devices, planner, observers=observers)
        self.handlers[LightFrame] = self._light_frame  # type: ignore[assignment]
        self._kin = self.rig.kinematics()

    def _light_frame(self, step: LightFrame) -> None:
        pose = None
        if step.light is not None:
            pose = self._kin.forward(step.joints)
        rec = self._claim(step.kind, pose, step.joints, step.pattern)
        if rec is None:
            return
        self._current = rec.step
        exposure = step.exposure_s or self.plan.capture.exposure_s or self.rig.camera.exposure_s
        if step.target != self._present:
            self.devices.present(step.target)
            self._present = step.target
        self.devices.set_levels(step.levels, hold_s=exposure)  # type: ignore[attr-defined]
        self._readback = step.joints
        self._shoot(rec, exposure, self.plan.capture.iso or self.rig.camera.iso,
                    retake_clipped=False)


@dataclass
class LightStageResult:
    """Where a light-stage capture went and how it ended."""

    session: SessionFolder
    counts: dict[str, int]
    device_seconds: float | None
    """Rig time the run took on the devices' clock (s)."""
    estimate: TimeEstimate
    """Predicted rig time of the whole sequence."""
    field: list[Path] | None = None
    """The reflectance field's EXRs (``SESSION/field``), written once an OLAT sequence is
    complete; None otherwise."""


def plan_lightstage(rig_path: str | Path, sequences: Sequence[str] = ("olat",), *,
                    white: bool = True, dark: bool = True,
                    exposure_s: float | None = None) -> TimeEstimate:
    """Time estimate of a light-stage capture without touching a device."""
    rig = load_rig(rig_path)
    stage = stage_config(rig)
    steps = capture_steps(stage, sequences, white=white, dark=dark)
    return estimate_s(stage, steps, exposure_s or rig.camera.exposure_s)


def capture_lightstage(
    rig_path: str | Path,
    out: str | Path,
    *,
    sequences: Sequence[str] = ("olat",),
    material: str | None = None,
    seed: int = 0,
    plan_path: str | Path | None = None,
    calibration: str | Path | None = None,
    white: bool = True,
    dark: bool = True,
    progress: Progress | None = None,
    observers: Sequence[Observer] = (),
    prompt: OperatorPrompt | None = None,
    on_open: OnOpen | None = None,
) -> LightStageResult:
    """Create a session folder at ``out`` and capture the light-stage sequence into it.

    ``sequences`` are names of :data:`acquisition.lightstage.sequences.SEQUENCES`; a white
    reference OLAT pass (``white``) and a dark frame (``dark``) come first. On real hardware
    ``prompt`` asks the operator to swap the sample and the white reference (refused before
    anything is created when there is none). ``on_open(folder, device_time_s)`` is called once
    the devices are open (e.g. to start a progress ETA from :func:`frame_durations`).
    """
    rig = load_rig(rig_path)
    stage = stage_config(rig)
    capture_steps(stage, sequences)  # unknown sequence names fail before anything is created
    if rig.simulated:
        material = material or DEFAULT_MATERIAL
        parse_material(material)
    elif rig.camera.driver != "simulated":
        require_operator(rig, prompt)
    with tempfile.TemporaryDirectory() as tmp:
        if plan_path is None:
            plan_path = Path(tmp) / "plan.toml"
            plan_path.write_text(DEFAULT_PLAN)
        folder, _ = create_session(out, rig_path, plan_path, material=material, seed=seed,
                                   calibration=calibration, scripted=True)
    with folder.journal() as journal:
        journal.set_meta(META_KEY, {"sequences": list(sequences), "white": white, "dark": dark})
    steps = capture_steps(stage, sequences, white=white, dark=dark)
    estimate = estimate_s(stage, steps, folder.plan().capture.exposure_s or rig.camera.exposure_s)
    folder.write_info(dataclasses.replace(folder.info, estimated_s=estimate.total_s))
    return resume_lightstage(folder.path, progress=progress, observers=observers, stage=stage,
                             prompt=prompt, on_open=on_open)


def resume_lightstage(
    session_dir: str | Path,
    *,
    progress: Progress | None = None,
    observers: Sequence[Observer] = (),
    stage: StageConfig | None = None,
    prompt: OperatorPrompt | None = None,
    on_open: OnOpen | None = None,
) -> LightStageResult:
    """Continue a light-stage session: replay its sequence, skipping the frames done
    (``prompt``, ``on_open``: see :func:`capture_lightstage`)."""
    folder = SessionFolder(session_dir)
    with folder.journal(readonly=True) as journal:
        meta = journal.meta(META_KEY)
    if meta is None:
        raise SessionError(f"{folder.path} is not a light-stage session: continue it with "
                           f"`gonio resume {folder.path}`")
    folder.require_writable()
    rig = folder.rig()
    stage = stage or stage_config(rig)
    steps, exposure_s = _sequence(folder, stage, meta)
    estimate = estimate_s(stage, steps, exposure_s)
    spec = folder.info.material
    material = parse_material(spec) if spec else None
    obs = list(observers)
    if progress is not None:
        obs.append(ProgressObserver(progress))
    planner = Planner.for_plan(rig, folder.plan())
    total = _frames(steps)
    with folder.journal() as journal:
        journal.set_meta(PLANNED_STEPS_META, total)
    with capture_lock(folder.path), open_lightstage(
            rig, material=material, seed=folder.info.seed, stage=stage, prompt=prompt) as devices:
        if on_open:
            on_open(folder, devices.device_time_s())
        engine = LightStageEngine(folder, devices, planner, obs)
        t0 = devices.device_time_s()
        counts = engine.run(steps, total)
        t1 = devices.device_time_s()
    field = None
    if counts.get("done", 0) == sum(counts.values()) and "olat" in meta["sequences"]:
        from acquisition.lightstage.field import write_field  # the field reads capture's meta

        field = write_field(folder.path, folder.path / FIELD_DIR)
    return LightStageResult(folder, counts, None if t0 is None or t1 is None else t1 - t0,
                            estimate, field)


FIELD_DIR = "field"
"""Sub-folder of a session where the reflectance field is written."""


def frame_durations(folder: SessionFolder, meta: dict[str, Any]) -> dict[int, float]:
    """Predicted rig time (s) of every journal step of the light-stage session ``folder``
    (``meta``: its journal's :data:`META_KEY` entry), ``{step: s}``: step k is the sequence's
    k-th frame (:func:`~acquisition.lightstage.sequences.frame_times_s`, which add up to the
    session's :class:`TimeEstimate`)."""
    stage = stage_config(folder.rig())
    steps, exposure_s = _sequence(folder, stage, meta)
    return dict(enumerate(frame_times_s(stage, steps, exposure_s)))


def _sequence(folder: SessionFolder, stage: StageConfig, meta: dict[str, Any]
              ) -> tuple[list[Step], float]:
    """The session's steps (as :func:`capture_lightstage` made them) and default exposure (s)."""
    steps = capture_steps(stage, meta["sequences"], white=meta["white"], dark=meta["dark"])
    return steps, folder.plan().capture.exposure_s or folder.rig().camera.exposure_s


def session_sequences(session_dir: str | Path) -> list[str]:
    """The sample sequences a light-stage session was started with."""
    folder = SessionFolder(session_dir)
    with folder.journal(readonly=True) as journal:
        meta = journal.meta(META_KEY)
    if meta is None:
        raise SessionError(f"{folder.path} is not a light-stage session")
    return list(meta["sequences"])


def _frames(steps: Sequence[object]) -> int:
    """LightFrame records (count_rows only knows the built-in records)."""
    return sum(isinstance(s, LightFrame) for s in steps)
