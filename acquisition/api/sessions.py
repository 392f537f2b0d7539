"""Sessions through the API: plan, capture, resume, scripted sessions, reduce.

Each run loads its rig and plan once and builds its planner once; the session folder object
carries them to the engine (:meth:`SessionFolder.adopt`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

from acquisition.config.plan import PlanSpec, check_plan_on_rig, load_plan
from acquisition.config.rig import RigConfig, load_rig, require_servo_rig
from acquisition.devices.rig import (
    OperatorPrompt,
    RigDevices,
    check_camera_driver,
    open_devices,
    require_operator,
)
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner, Sweep
from acquisition.planning.timing import TimeModel
from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.checkpoint import checkpoint_path, write_table
from acquisition.reduction.point import Reduction, reduce_session
from acquisition.session.alignment import alignment_of, bundle_at
from acquisition.session.capture import CaptureEngine
from acquisition.session.engine import SessionEngine
from acquisition.session.folder import SessionFolder, create_session
from acquisition.session.journal import StepRecord
from acquisition.session.observers import Observer
from acquisition.session.runlock import capture_lock
from acquisition.session.status import DEFAULT_TABLE, LINK_STATS_META
from acquisition.session.steps import CUSTOM, Step, count_rows, pose_steps
from acquisition.simworld.materials import DEFAULT_MATERIAL, parse_material
from acquisition.simworld.servos import check_sim_faults
from acquisition.tables.isotropic import WHAT as TABLE_WHAT
from acquisition.tables.isotropic import is_table_file
from drivers.errors import ConfigError, SessionError, StorageError
from drivers.storage import check_output

Progress = Callable[[int, int, StepRecord], None]
OnOpen = Callable[[SessionFolder, float | None], None]
"""Called once a run's devices are open: ``(session folder, device time s or None)``."""


@dataclass
class CaptureResult:
    """Where a capture went and how it ended."""

    session: SessionFolder
    counts: dict[str, int]
    device_seconds: float | None
    """Time the capture took on the devices' clock (the simulated clock for simulated rigs)."""
    streamed: dict[str, object] | None = None
    """With ``reduce=True``, the streaming reduction's report: ``{"table": path, "frames": n,
    "pending": n}``, or ``{"error": one line}`` (see :mod:`acquisition.api.streaming`)."""


def plan_sweep(plan_path: str | Path, rig_path: str | Path) -> Sweep:
    """Plan a sweep without moving anything: accepted/rejected poses and the time estimate.

    Raises :class:`SessionError` when the plan leaves no pose to measure (as ``capture`` does).
    """
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    require_servo_rig(rig, "gonio plan")
    check_plan_on_rig(plan, rig)
    planner = Planner.for_plan(rig, plan)
    wr = rig.white_reference
    start = planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi))
    sweep = planner.plan(plan.poses(), start)
    if not sweep.steps:
        rejected = ", ".join(f"{n} {r}" for r, n in sweep.rejected_counts().items())
        raise SessionError(f"plan {plan.path} leaves no measurable pose on this rig ({rejected}): "
                           "check its units and ranges")
    return sweep


def predicted_step_s(records: Iterable[StepRecord], model: TimeModel,
                     start: Mapping[str, float] | None = None, *,
                     move_s: Callable[[Mapping[str, float], Mapping[str, float]], float] | None = None,
                     ) -> dict[int, float]:
    """Predicted rig time (s) of each journal step, in journal order: ``{step: s}``.

    A step whose joints differ from the previous step's (the first step always: the engine
    moves once to where it starts) costs the move from there (:meth:`TimeModel.move_s`, from
    ``start`` for the first) plus settle and bus time; every frame costs the exposure, times
    its bracket factor (``note`` ``"bracket=F"``). Custom steps cost nothing. ``move_s``
    times a move (default :meth:`TimeModel.move_s`; :meth:`Planner.leg_s` times it as routed).
    """
    costs = model.costs
    move_s = move_s or model.move_s
    out: dict[int, float] = {}
    at: Mapping[str, float] | None = None
    for rec in records:
        t = 0.0
        joints = rec.joints_cmd
        if joints and (at is None or not _same(at, joints)):
            t += move_s(at if at is not None else (start or joints), joints)
            t += costs.settle_s + costs.bus_cycle_s
            at = joints
        if rec.kind != CUSTOM:
            factor = 1.0
            if rec.note and rec.note.startswith("bracket="):
                factor = float(rec.note.removeprefix("bracket="))
            t += costs.exposure_s * factor
        out[rec.step] = t
    return out


def _same(a: Mapping[str, float], b: Mapping[str, float]) -> bool:
    return a.keys() == b.keys() and all(math.isclose(a[k], b[k], abs_tol=1e-9) for k in a)


def step_durations(session: str | Path | SessionFolder, *, pending_only: bool = True
                   ) -> dict[int, float]:
    """Predicted rig time (s) of a pre-planned session's journal steps (the steps not done
    yet by default), from the planner's time model (see :func:`predicted_step_s`); for a
    light-stage session, from its sequence's time estimate
    (:func:`acquisition.lightstage.capture.frame_durations`)."""
    from acquisition.lightstage.capture import META_KEY, frame_durations

    folder = session if isinstance(session, SessionFolder) else SessionFolder(session)
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
        lightstage = journal.meta(META_KEY)
    if lightstage is not None:
        predicted = frame_durations(folder, lightstage)
    else:
        planner = folder.planner()
        predicted = predicted_step_s(records, planner.time_model, planner.reference_joints(),
                                     move_s=planner.leg_s)
    if pending_only:
        done = {r.step for r in records if r.status == "done"}
        predicted = {k: v for k, v in predicted.items() if k not in done}
    return predicted


def run_session(
    folder: SessionFolder,
    *,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
    on_open: OnOpen | None = None,
    observers: Sequence[Observer] = (),
    prompt: OperatorPrompt | None = None,
    reduce: bool = False,
) -> CaptureResult:
    """Run (or continue) every step of a pre-planned session that is not done yet.

    ``prompt`` asks the operator to swap the sample and the white reference on a real rig.
    ``reduce``: reduce the frames as they land, in a worker process
    (:class:`~acquisition.api.streaming.StreamingWorker`), into the session's table.
    """
    rig = folder.rig()
    material = parse_material(folder.info.material) if folder.info.material else None
    if rig.simulated and material is None:
        raise SessionError(f"{folder.path}: a simulated rig needs a material (--material)")
    planner = folder.planner()
    worker = None
    try:
        with capture_lock(folder.path):
            if reduce:  # started first: it loads while the devices open
                from acquisition.api.streaming import StreamingWorker, pending_steps

                if pending_steps(folder) or not (folder.path / DEFAULT_TABLE).exists():
                    worker = StreamingWorker(folder)  # else its table (calibrated?) is kept
            with open_devices(rig, planner, material=material, seed=folder.info.seed,
                              sim_faults=sim_faults, prompt=prompt) as devices:
                counts, t0, t1 = _run_engine(folder, devices, planner, progress, observers,
                                             on_open)
    finally:  # the lock is released: the worker sees the capture end and finishes
        streamed = None if worker is None else worker.result()
    return CaptureResult(folder, counts, None if t0 is None or t1 is None else t1 - t0, streamed)


def refuse_calibration_of_lightstage(path: str | Path, calibration: object) -> None:
    """ConfigError when a calibration bundle is given for a light-stage session."""
    if calibration is not None:
        raise ConfigError(f"{path} is a light-stage session, calibrated by its own OLAT white "
                          "frames: drop --calibration")


def _run_engine(folder: SessionFolder, devices: RigDevices, planner: Planner,
                progress: Progress | None, observers: Sequence[Observer],
                on_open: OnOpen | None) -> tuple[dict[str, int], float | None, float | None]:
    """Every step not done yet, on open devices: the journal's counts, the device clock at
    the start and the end (None on real hardware)."""
    if on_open:
        on_open(folder, devices.device_time_s())
    t0 = devices.device_time_s()
    engine = CaptureEngine(folder, devices, devices.roi_saturated, progress, observers, planner)
    with keeping_run_health(folder, devices):
        counts = engine.run()
    return counts, t0, devices.device_time_s()


@contextmanager
def keeping_run_health(folder: SessionFolder, devices: RigDevices) -> Iterator[None]:
    """Record the run's health when the block ends; when the block failed, a journal that
    cannot be written then (full disk) does not hide the block's own error."""
    try:
        yield
    except BaseException:
        with suppress(StorageError):
            record_run_health(folder, devices)
        raise
    record_run_health(folder, devices)


def record_run_health(folder: SessionFolder, devices: RigDevices) -> None:
    """Keep the run's bus retries and resends per axis and any simulated collision in the
    session's journal (``gonio info`` shows them), also when the run failed."""
    with folder.journal() as journal:
        runs = journal.meta(LINK_STATS_META, [])
        journal.set_meta(LINK_STATS_META, [*runs, devices.link_stats()])
        for line in devices.collisions():
            journal.log("error", f"simulated collision: {line}")


def capture(
    rig_path: str | Path,
    plan_path: str | Path,
    out: str | Path,
    *,
    material: str | None = None,
    seed: int = 0,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
    calibration: str | Path | None = None,
    observers: Sequence[Observer] = (),
    on_open: OnOpen | None = None,
    prompt: OperatorPrompt | None = None,
    reduce: bool = False,
) -> CaptureResult:
    """Create a session folder at ``out`` and capture the plan on the rig.

    ``calibration`` (a file or folder) is copied into the session for provenance; a bundle's
    geometric calibration (``gonio calibrate geometry``) is applied by the planner: the joint
    targets realise each pose on the real rig.
    ``reduce=True`` reduces the frames as they land, in a worker process beside the capture,
    into ``out/brdf.h5`` (:mod:`acquisition.api.streaming`; the result's ``streamed``).
    ``on_open(folder, device_time_s)`` is called once the devices are open (e.g. to start a
    progress ETA from :func:`step_durations`). ``prompt(target)`` asks the operator to put
    the ``"sample"`` or ``"white"`` reference on a real rig (refused without one).
    """
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    _check_before_creating(rig, plan, "gonio capture", sim_faults, prompt)
    material = _check_material(rig, material)
    planner = Planner.for_plan(rig, plan, alignment_of(bundle_at(calibration), rig))
    folder, _ = create_session(out, rig, plan, material=material, seed=seed,
                               calibration=calibration, planner=planner)
    return run_session(folder, sim_faults=sim_faults, progress=progress, observers=observers,
                       on_open=on_open, prompt=prompt, reduce=reduce)


def _check_before_creating(rig: RigConfig, plan: PlanSpec, command: str,
                           sim_faults: Sequence[str], prompt: OperatorPrompt | None) -> None:
    """Everything the rig, plan and options allow to check before a session folder is created
    or a device opened (ConfigError, one line): the rig's kind, what the plan asks of its
    camera, the camera driver, an operator for a real camera, the fault specs."""
    require_servo_rig(rig, command)
    check_plan_on_rig(plan, rig)
    check_camera_driver(rig)
    check_sim_faults(rig, sim_faults)
    if rig.camera.driver != "simulated":
        require_operator(rig, prompt)


def _check_material(rig: RigConfig, material: str | None) -> str | None:
    if rig.simulated:
        material = material or DEFAULT_MATERIAL
        parse_material(material)  # fail before creating anything
    return material


def resume(
    session_dir: str | Path,
    *,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
    observers: Sequence[Observer] = (),
    on_open: OnOpen | None = None,
    prompt: OperatorPrompt | None = None,
    reduce: bool = False,
) -> CaptureResult:
    """Continue an interrupted session where it stopped (gonio or light-stage).

    ``on_open``, ``prompt`` and ``reduce`` as for :func:`capture` (a light stage's field is
    made at its end; ``reduce`` does not apply).
    """
    from acquisition.lightstage.reduce import is_lightstage_session

    if is_lightstage_session(session_dir):
        from acquisition.lightstage.capture import resume_lightstage

        if sim_faults:  # refused: a light stage has no servo bus
            check_sim_faults(SessionFolder(session_dir).rig(), sim_faults)
        return resume_lightstage(session_dir, progress=progress, observers=observers,  # type: ignore[return-value]
                                 prompt=prompt, on_open=on_open)
    folder = SessionFolder(session_dir)
    folder.require_writable()
    if sim_faults:
        check_sim_faults(folder.rig(), sim_faults)
    return run_session(folder, sim_faults=sim_faults, progress=progress,
                       observers=observers, on_open=on_open, prompt=prompt, reduce=reduce)


class ScriptedSession:
    """An open session with its devices, running plans of step records.

    Obtain one from :func:`scripted_session`. See :mod:`acquisition.session.steps` for the records.
    """

    def __init__(self, folder: SessionFolder, devices: RigDevices, planner: Planner) -> None:
        self.folder = folder
        self.devices = devices
        self.planner = planner
        self.engine = SessionEngine(folder, devices, planner, saturated=devices.roi_saturated)

    @property
    def rig(self) -> RigConfig:
        return self.engine.rig

    @property
    def plan(self) -> PlanSpec:
        return self.engine.plan

    @property
    def reference_joints(self) -> dict[str, float]:
        """The joints (degrees) of the white reference's pose."""
        return dict(self.engine.ref_joints)

    def run(
        self,
        steps: Iterable[Step],
        observers: Sequence[Observer] = (),
        total: int | None = None,
    ) -> dict[str, int]:
        """Run a plan (list or generator of step records); returns the journal's status counts.

        Steps the journal holds as done are skipped, so rerunning the same script after a
        crash continues it. ``total`` (journal steps) defaults to the plan's length for a list.
        """
        if total is None and isinstance(steps, Sequence):
            total = count_rows(steps)
        self.engine.observers = list(observers)
        return self.engine.run(steps, total)

    def sweep(self, poses: Sequence[Pose] | None = None, **kwargs: object) -> list[Step]:
        """The standard sweep (references, move/expose/checkpoint per pose) as step records.

        ``poses`` defaults to the plan file's; unsafe poses are dropped by the planner.
        Keyword arguments go to :func:`acquisition.session.steps.sweep_steps`.
        """
        chosen = self.plan.poses() if poses is None else list(poses)
        kwargs.setdefault("reference_every", self.plan.capture.reference_every)
        return list(pose_steps(self.planner, chosen, self.engine.ref_joints, **kwargs))  # type: ignore[arg-type]


@contextmanager
def scripted_session(
    out: str | Path,
    rig_path: str | Path,
    plan_path: str | Path,
    *,
    material: str | None = None,
    seed: int = 0,
    calibration: str | Path | None = None,
    resume: bool = False,
    sim_faults: Sequence[str] = (),
    prompt: OperatorPrompt | None = None,
) -> Iterator[ScriptedSession]:
    """Open the rig for a scripted capture into the session folder ``out``.

    The plan file gives the table bins and capture settings; the script gives the steps.
    With ``resume=True`` an existing scripted session at ``out`` is reopened (rerun the same
    script to continue it); otherwise ``out`` must not exist.
    """
    if resume and Path(out).exists():
        folder = SessionFolder(out)
        if not folder.info.scripted:
            raise SessionError(f"{out} is not a scripted session: continue it with `gonio resume {out}`")
        folder.require_writable()
        check_sim_faults(folder.rig(), sim_faults)
    else:
        rig, plan = load_rig(rig_path), load_plan(plan_path)
        _check_before_creating(rig, plan, "a scripted session", sim_faults, prompt)
        material = _check_material(rig, material)
        folder, _ = create_session(out, rig, plan, material=material, seed=seed,
                                   calibration=calibration, scripted=True,
                                   planner=Planner.for_plan(
                                       rig, plan, alignment_of(bundle_at(calibration), rig)))
    rig = folder.rig()
    spec = folder.info.material
    mat = parse_material(spec) if spec else None
    planner = folder.planner()
    with capture_lock(folder.path), open_devices(
            rig, planner, material=mat, seed=folder.info.seed, sim_faults=sim_faults,
            prompt=prompt) as devices, keeping_run_health(folder, devices):
        yield ScriptedSession(folder, devices, planner)


def reduce(
    session_dir: str | Path | SessionFolder,
    table_path: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    *,
    calibration: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
) -> Reduction:
    """Reduce a session into its isotropic BRDF table, saved as HDF5 (default: DIR/brdf.h5).

    ``calibration``: a calibration bundle to apply (made after the capture, say) instead of
    the session's own copy.

    ``session_dir`` is the folder, or a run's :class:`SessionFolder` (its rig and plan are
    used as loaded). Nothing is written into the session but the default table: a session on
    read-only media reduces to a writable ``table_path``. An output that would overwrite the
    session's own files, or an existing file that is not a gonio table, is refused before
    reducing.

    An image-based session checkpoints its partial tables beside the table
    (``NAME.checkpoint.h5``, :mod:`acquisition.reduction.checkpoint`) every
    ``checkpoint_every`` frames (0: only once all are binned): reduced again after an
    interruption, it resumes from there, to the same table byte for byte. The checkpoint is
    deleted once the table is written.
    """
    from acquisition.lightstage.reduce import is_lightstage_session, reduce_lightstage_session

    path = session_dir.path if isinstance(session_dir, SessionFolder) else session_dir
    out = Path(table_path) if table_path else Path(path) / DEFAULT_TABLE
    check_output(out, what=TABLE_WHAT, ours=is_table_file, inputs=(path,))
    resume = checkpoint_path(out)
    if is_lightstage_session(path):
        refuse_calibration_of_lightstage(path, calibration)
        result: Reduction = reduce_lightstage_session(path, progress)
    else:
        result = reduce_session(session_dir, progress, bundle=calibration, checkpoint=resume,
                                checkpoint_every=checkpoint_every)
    write_table(result, out, path)
    return result


