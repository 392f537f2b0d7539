"""The session engine: runs a plan of step records (:mod:`acquisition.session.steps`) on open
devices against the journal, skipping what is done, so a run stopped by Ctrl-C, a crash or a
power cut continues exactly where it stopped. Every frame is written atomically, re-opened
(:mod:`acquisition.session.frames`) and hashed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from acquisition.session.folder import SessionFolder, frame_name, reference_geometry
from acquisition.session.frames import check_raw_frame
from acquisition.session.hdr import HDR_DONE_META, HDR_NOTE, camera_noise_model, hdr_group
from acquisition.session.journal import Journal, StepRecord
from acquisition.session.steps import (
    CUSTOM,
    DARK,
    POSE,
    REFERENCE,
    Checkpoint,
    Custom,
    Dark,
    Expose,
    ExposeHDR,
    Move,
    Reference,
    Step,
)
from calibration.hdr import BracketPolicy, bracket
from drivers.errors import (
    CommunicationError,
    GonioError,
    HardwareError,
    SafetyStop,
    SessionError,
)
from drivers.storage import Discard, atomic_output, is_partial, sha256_file

if TYPE_CHECKING:
    from acquisition.session.observers import Observer


class CaptureDevices(Protocol):
    """What the engine needs from an open rig (real or simulated)."""

    stopped: str
    """What :meth:`stop_motion` leaves, for the Ctrl-C message ("all axes stopped, ...")."""

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


ProgressCallback = Callable[[int, int, StepRecord], None]
"""Called after each completed step with (done, total, record)."""


@dataclass(frozen=True)
class StepEvent:
    """A journal step just completed (what observers receive)."""

    record: StepRecord
    done: int
    """Journal steps done so far (this one included)."""
    total: int | None
    """Journal steps known so far (None: an open-ended plan has not said)."""
    frame: Path | None
    """The frame written, if the step took one."""


@dataclass
class StepContext:
    """What a :class:`~acquisition.session.steps.Custom` step's function receives."""

    folder: SessionFolder
    devices: CaptureDevices
    journal: Journal
    step: int
    pose: Pose | None
    """The last target pose (degrees), if any."""
    extra: dict[str, Any] = field(default_factory=dict)


Handler = Callable[[Step], None]


class SessionEngine:
    """Runs a plan of step records on open devices, journaling every frame.

    Parameters
    ----------
    folder
        The session.
    devices
        An open rig (see :mod:`acquisition.devices.rig`).
    planner
        Guards and solves moves (joints for a pose given without them).
    saturated
        ``saturated(frame_path) -> bool``: whether the region of interest clipped; the frame is
        retaken at a quarter of the exposure, up to the rig's ``max_exposure_retries``.
    observers
        :class:`acquisition.session.observers.Observer` objects told of start, steps, checkpoints,
        errors and the end.

    Notes
    -----
    Each record producing a journal row gets the next step number in plan order. A row the
    journal holds as done is skipped (its move too, when nothing at that pose is left to do);
    a row that differs from the journal's (kind, joints, note) stops the run with a
    :class:`SessionError`. :attr:`handlers` maps record types to methods; add your own record
    types there.
    """

    def __init__(
        self,
        folder: SessionFolder,
        devices: CaptureDevices,
        planner: Planner,
        *,
        saturated: Callable[[Path], bool] | None = None,
        observers: Sequence[Observer] = (),
    ) -> None:
        self.folder = folder
        self.devices = devices
        self.planner = planner
        self.saturated = saturated or (lambda _path: False)
        self.observers = list(observers)
        self.rig = folder.rig()
        self.plan = folder.plan()
        self.ref_pose, self.ref_joints = reference_geometry(self.rig, planner)
        self.handlers: dict[type, Handler] = {
            Move: self._move,  # type: ignore[dict-item]
            Expose: self._expose,  # type: ignore[dict-item]
            ExposeHDR: self._expose_hdr,  # type: ignore[dict-item]
            Dark: self._dark,  # type: ignore[dict-item]
            Reference: self._reference,  # type: ignore[dict-item]
            Checkpoint: self._checkpoint,  # type: ignore[dict-item]
            Custom: self._custom,  # type: ignore[dict-item]
        }
        self._stop_requested = False
        self._journal: Journal | None = None

    # ------------------------------------------------------------------ control
    def request_stop(self) -> None:
        """Stop at the next checkpoint (a deferred, clean stop; safe from a signal handler)."""
        self._stop_requested = True

    def verify_done_steps(self, journal: Journal) -> int:
        """Send back to 'planned' every done step whose frame is missing or fails its hash.

        Half-written frames (:func:`drivers.storage.is_partial`) are deleted. Returns the
        number of steps to redo.
        """
        redo = 0
        for partial in sorted(p for p in self.folder.frames_dir.iterdir() if is_partial(p)):
            partial.unlink()
            journal.log("warning", f"discarded the half-written frame {partial.name}")
        for rec in journal.steps():
            if rec.status != "done" or rec.kind == CUSTOM:
                continue
            frame = self.folder.frames_dir / (rec.frame or "")
            if not rec.frame or not frame.is_file():
                journal.mark_redo(rec.step, f"frame {rec.frame} missing: retaking")
                redo += 1
            elif sha256_file(frame) != rec.sha256:
                journal.mark_redo(rec.step, f"frame {rec.frame} fails its SHA-256: retaking")
                redo += 1
        return redo

    def run(self, steps: Iterable[Step], total: int | None = None) -> dict[str, int]:
        """Run ``steps`` (replaying what the journal holds as done); returns status counts.

        ``total`` is the number of journal steps the plan will produce, for progress; by
        default the journal's row count (exact for a pre-planned session).
        """
        with self.folder.journal() as journal:
            self._journal = journal
            try:
                return self._run(journal, steps, total)
            finally:
                self._journal = None

    def _run(self, journal: Journal, steps: Iterable[Step], total: int | None) -> dict[str, int]:
        self.verify_done_steps(journal)
        records = list(journal.steps())
        self._done = sum(r.status == "done" for r in records)
        self._total = max(total, len(records)) if total is not None else (len(records) or None)
        self._next = 0
        self._target: tuple[Pose, dict[str, float]] | None = None
        self._at: dict[str, float] | None = None
        self._readback: dict[str, float] = {}
        self._present: str | None = None
        self._current: int | None = None
        self._stop_requested = False
        with self.devices.host_work():
            journal.log("info", f"run started ({self._done} of {len(records)} journal steps done)")
            for ob in self.observers:
                ob.start(self.folder, self._total, self._done)
        try:
            for step in steps:
                handler = self.handlers.get(type(step))
                if handler is None:
                    raise SessionError(
                        f"unknown plan step {step!r}: register a handler in SessionEngine.handlers"
                    )
                handler(step)
            with self.devices.host_work():
                self._check_no_gap(journal)
        except KeyboardInterrupt:
            self.devices.stop_motion()
            journal.try_log("warning", "interrupted by the operator", self._current)
            exc = SafetyStop(
                f"interrupted at step {self._current}: "
                f"{self.devices.stopped}; "
                f"continue with `gonio resume {self.folder.path}`"
            )
            self._notify_error(exc)
            raise exc from None
        except GonioError as exc:
            if isinstance(exc, HardwareError | CommunicationError) and "gonio resume" not in str(exc):
                exc.args = (f"{exc}; then continue with `gonio resume {self.folder.path}`",)
            journal.try_log("error", str(exc), self._current)
            self._notify_error(exc)
            raise
        counts = journal.counts()
        journal.log("info", f"run ended: {counts}")
        for ob in self.observers:
            ob.finish(counts)
        return counts

    def _notify_error(self, exc: BaseException) -> None:
        for ob in self.observers:
            ob.error(exc)

    def _check_no_gap(self, journal: Journal) -> None:
        left = [r.step for r in journal.steps() if r.step >= self._next and r.status != "done"]
        if left:
            raise SessionError(
                f"{self.folder.path}: the plan ended before journal step {left[0]} "
                f"({len(left)} not done): run the plan the session was started with"
            )

    # ------------------------------------------------------------------ journal matching
    def _claim(
        self, kind: str, pose: Pose | None, joints: Mapping[str, float], note: str | None = None
    ) -> StepRecord | None:
        """The journal row for the next step number; None when it is already done."""
        assert self._journal is not None
        n = self._next
        self._next += 1
        with self.devices.host_work():
            return self._match(n, kind, pose, joints, note)

    def _match(
        self, n: int, kind: str, pose: Pose | None, joints: Mapping[str, float], note: str | None
    ) -> StepRecord | None:
        assert self._journal is not None
        rec = self._journal.record(n)
        if rec is None:
            rec = self._journal.add_step(n, kind, None if pose is None else pose.as_tuple(),
                                         dict(joints), note)
            if self._total is not None and n >= self._total:
                self._total = n + 1
        elif rec.kind != kind or not _same_joints(rec.joints_cmd, joints) or (
            note is not None and rec.note != note
        ):
            raise SessionError(
                f"{self.folder.path}: plan step {n} is a {kind} at {dict(joints)} but the "
                f"journal holds a {rec.kind} at {rec.joints_cmd}: resume with the same plan"
            )
        return None if rec.status == "done" else rec

    # ------------------------------------------------------------------ handlers
    def _move(self, step: Move) -> None:
        if step.joints is None:
            start = self._target[1] if self._target else self.ref_joints
            joints = dict(self.planner.joints_for(step.pose, start))
        else:
            joints = {k: float(v) for k, v in step.joints.items()}
            self.planner.check_joints(joints)
        self._target = (step.pose, joints)

    def _require_target(self, what: str) -> tuple[Pose, dict[str, float]]:
        if self._target is None:
            raise SessionError(f"plan step {self._next}: {what} before any Move: add a Move first")
        return self._target

    def _expose(self, step: Expose) -> None:
        pose, joints = self._require_target("Expose")
        base = step.exposure_s or self.plan.capture.exposure_s or self.rig.camera.exposure_s
        iso = step.iso or self.plan.capture.iso or self.rig.camera.iso
        multi = len(step.bracket) > 1
        for factor in step.bracket:
            rec = self._claim(POSE, pose, joints, f"bracket={factor:g}" if multi else None)
            if rec is None:
                continue
            self._go(joints, "sample")
            self._shoot(rec, base * factor, iso)

    def _expose_hdr(self, step: ExposeHDR) -> None:
        pose, joints = self._require_target("ExposeHDR")
        assert self._journal is not None
        base = step.exposure_s or self.plan.capture.exposure_s or self.rig.camera.exposure_s
        iso = step.iso or self.plan.capture.iso or self.rig.camera.iso
        first = self._next
        group = f"{HDR_NOTE}{first}"
        with self.devices.host_work():
            complete = self._journal.meta(f"{HDR_DONE_META}{first}")
        if complete is not None:  # a finished bracket: retake only frames sent back for redo
            for k in range(int(complete)):
                rec = self._claim(POSE, pose, joints, f"{group}:{k}")
                if rec is not None:
                    self._go(joints, "sample")
                    self._shoot(rec, rec.exposure_s or base, iso, retake_clipped=False)
            return
        # Not recorded as complete: (re)shoot the whole bracket, reusing any rows a
        # bracket interrupted part-way left behind.
        with self.devices.host_work():
            cal = self._bundle()
            noise = camera_noise_model(self.rig, iso, cal)
        taken: list[float] = []

        def capture(exposure_s: float) -> Path:
            rec = self._claim_again(POSE, pose, joints, f"{group}:{len(taken)}")
            taken.append(exposure_s)
            self._go(joints, "sample")
            return self._shoot(rec, exposure_s, iso, retake_clipped=False)

        x0, y0, x1, y1 = self.rig.camera.roi
        policy = BracketPolicy(target_snr=step.target_snr or self.plan.capture.target_snr,
                               step=step.step, max_frames=step.max_frames)
        with self.devices.host_work():
            extra = {} if cal is None else {"dark_for": cal.dark_for, "flat": cal.flat,
                                            "bad_pixels": cal.bad_pixels}
        bracket(capture, (x0, y0, x1 - x0, y1 - y0), noise, start_exposure_s=base,
                policy=policy, **extra)
        while True:  # rows of an earlier, longer attempt: fill them (more frames only help)
            with self.devices.host_work():
                stale = self._journal.record(self._next)
            if stale is None or hdr_group(stale.note) != first:
                break
            capture(stale.exposure_s or max(taken))
        with self.devices.host_work():
            self._journal.set_meta(f"{HDR_DONE_META}{first}", len(taken))

    def _bundle(self) -> Any:
        """The session's calibration bundle (cached), or None."""
        if not hasattr(self, "_cal"):
            from calibration.bundle import SCALARS_FILE, CalibrationBundle

            copied = self.folder.calibration
            self._cal = (CalibrationBundle.open(copied) if copied is not None
                         and (Path(copied) / SCALARS_FILE).is_file() else None)
        return self._cal

    def _claim_again(
        self, kind: str, pose: Pose, joints: Mapping[str, float], note: str
    ) -> StepRecord:
        """Like :meth:`_claim`, but a done row is returned too (to be shot again)."""
        assert self._journal is not None
        n = self._next
        self._next += 1
        with self.devices.host_work():
            rec = self._match(n, kind, pose, joints, note) or self._journal.record(n)
        assert rec is not None
        if rec.status == "done":
            self._done -= 1
        return rec

    def _dark(self, step: Dark) -> None:
        pose, joints = self._require_target("Dark")
        rec = self._claim(DARK, pose, joints)
        if rec is None:
            return
        light = getattr(self.devices, "light", None)
        if light is None:
            raise SessionError("this rig cannot switch its light off for a dark frame: "
                               "remove Dark steps or use a rig with light control")
        exposure = step.exposure_s or self.plan.capture.exposure_s or self.rig.camera.exposure_s
        self._go(joints, None)
        light(False)
        try:
            self._shoot(rec, exposure, step.iso or self.plan.capture.iso or self.rig.camera.iso,
                        retake_clipped=False)
        finally:
            light(True)

    def _reference(self, step: Reference) -> None:
        pose = step.pose or self.ref_pose
        joints = dict(step.joints) if step.joints is not None else (
            self.ref_joints if step.pose is None else dict(self.planner.joints_for(pose))
        )
        rec = self._claim(REFERENCE, pose, joints)
        if rec is None:
            return
        exposure = step.exposure_s or self.plan.capture.exposure_s or self.rig.camera.exposure_s
        self._go(joints, "white")
        self._shoot(rec, exposure, self.plan.capture.iso or self.rig.camera.iso)

    def _checkpoint(self, step: Checkpoint) -> None:
        for ob in self.observers:
            ob.checkpoint(step.label, self._done)
        if self._stop_requested:
            assert self._journal is not None
            self._journal.log("warning", f"stopped at a checkpoint {step.label}".strip(),
                              self._next)
            raise SafetyStop(
                f"stopped at a checkpoint before step {self._next}: "
                f"continue with `gonio resume {self.folder.path}`"
            )

    def _custom(self, step: Custom) -> None:
        rec = self._claim(CUSTOM, None, {}, step.name)
        if rec is None:
            return
        assert self._journal is not None
        self._current = rec.step
        with self.devices.host_work():
            self._journal.mark_started(rec.step)
        ctx = StepContext(self.folder, self.devices, self._journal, rec.step,
                          self._target[0] if self._target else None)
        step.fn(ctx)
        with self.devices.host_work():
            self._journal.mark_called(rec.step, self.devices.device_time_s())
            self._completed(rec.step, None)

    # ------------------------------------------------------------------ device work
    def _go(self, joints: dict[str, float], target: str | None) -> None:
        """Present ``target`` and move to ``joints`` if not there already."""
        if target is not None and target != self._present:
            self.devices.present(target)
            self._present = target
        if self._at != joints:
            self._readback = self.devices.move_to(joints)
            self._at = joints

    def _shoot(self, rec: StepRecord, exposure_s: float, iso: int, *,
               retake_clipped: bool = True) -> Path:
        """Expose ``rec``'s frame (retaking a clipped one shorter) and journal it as done."""
        assert self._journal is not None
        self._current = rec.step
        with self.devices.host_work():
            self._journal.mark_started(rec.step)
        seed_base = self.folder.info.seed * 1_000_003 + rec.step * 17
        name = frame_name(rec.step)
        final = self.folder.frames_dir / name
        retries = self.rig.camera.max_exposure_retries if retake_clipped else 0
        for attempt in range(retries + 1):
            try:
                with atomic_output(final, what="frame", ours=True, own_session=True,
                                   verify=self._frame_verifier(attempt < retries),
                                   retry=f", then `gonio resume {self.folder.path}`") as tmp:
                    self.devices.capture(tmp, exposure_s, iso, seed_base + attempt)
            except _Retake:
                exposure_s /= 4.0
                continue
            except _Failed as failed:
                raise failed.error from None
            break
        with self.devices.host_work():
            self._journal.mark_done(
                rec.step, frame=name, sha256=sha256_file(final), joints_read=self._readback,
                exposure_s=exposure_s, iso=iso, device_time_s=self.devices.device_time_s(),
            )
            self._completed(rec.step, final)
        return final

    def _frame_verifier(self, retake_clipped: bool) -> Callable[[Path], None]:
        """The frame writer's ``verify``: the frame re-opens whole (:func:`check_raw_frame`,
        no pixel decoded), then, if ``retake_clipped``, a clipped ROI drops it for a retake."""
        def verify(tmp: Path) -> None:
            with self.devices.host_work():
                check_raw_frame(tmp)
                if not retake_clipped:
                    return
                try:
                    clipped = self.saturated(tmp)
                except GonioError as exc:  # its own one line, not the writer's "does not read back"
                    raise _Failed(exc) from exc
                if clipped:
                    raise _Retake()
        return verify

    def _completed(self, step: int, frame: Path | None) -> None:
        assert self._journal is not None
        self._done += 1
        rec = self._journal.record(step)
        assert rec is not None
        event = StepEvent(rec, self._done, self._total, frame)
        for ob in self.observers:
            ob.step(event)


def _same_joints(a: Mapping[str, float], b: Mapping[str, float]) -> bool:
    return a.keys() == b.keys() and all(math.isclose(a[k], b[k], abs_tol=1e-9) for k in a)


class _Retake(Discard):
    """Internal: discard the frame just written and expose again."""


class _Failed(Discard):
    """Internal: the clip test failed with ``error``; drop the frame and raise it."""

    def __init__(self, error: GonioError) -> None:
        super().__init__(str(error))
        self.error = error
