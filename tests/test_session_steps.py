"""Step records and the session engine: plans as data, journal replay, observers."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition import api
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import PlannedPose, Sweep
from acquisition.reduction.live import LiveReduction
from acquisition.session.engine import SessionEngine
from acquisition.session.folder import JOURNAL_FILE, create_session
from acquisition.session.journal import Journal
from acquisition.session.observers import CallbackObserver, Observer
from acquisition.session.steps import (
    Checkpoint,
    Custom,
    Dark,
    Expose,
    Move,
    Reference,
    count_rows,
    sweep_steps,
)
from drivers.errors import SafetyStop, SessionError
from drivers.storage import is_partial, partial_name

PLAN = """
format_version = 1
name = "tiny"
[sampling]
kind = "grid"
theta_i = { start = 30, stop = 30, step = 10 }
theta_r = { start = 30, stop = 40, step = 10 }
delta_phi = { start = 180, stop = 180, step = 10 }
"""


@pytest.fixture
def plan_path(tmp_path: Path) -> Path:
    p = tmp_path / "plan.toml"
    p.write_text(PLAN)
    return p


class FakeRig:
    """Records every device call; frames are bytes derived from the frame seed."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, Any]] = []

    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        self.calls.append(("move", dict(joints)))
        return dict(joints)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> None:
        self.calls.append(("capture", (exposure_s, frame_seed)))
        path.write_bytes(f"{frame_seed}:{exposure_s}".encode())

    def present(self, target: str) -> None:
        self.calls.append(("present", target))

    def light(self, on: bool) -> None:
        self.calls.append(("light", on))

    def stop_motion(self) -> None:
        self.calls.append(("stop", None))

    def device_time_s(self) -> float | None:
        return None

    def host_work(self) -> nullcontext[None]:
        return nullcontext()

    def kinds(self) -> list[str]:
        return [c[0] for c in self.calls]


def _engine(tmp_path: Path, rig_sim_path: Path, plan_path: Path, name: str = "s") -> tuple[
    SessionEngine, FakeRig
]:
    folder, _ = create_session(tmp_path / name, rig_sim_path, plan_path, material=None,
                               scripted=True)
    rig = FakeRig()
    return SessionEngine(folder, rig, folder.planner()), rig


def test_sweep_steps_is_the_standard_capture_order() -> None:
    poses = [PlannedPose(i, Pose(10 + 20 * i, 20, 180), {"a": i + 1.0}, 0.0) for i in range(3)]
    sweep = Sweep(poses, [], {}, 0.0, 0.0)
    ref = Reference()
    assert list(sweep_steps(sweep, reference_every=2)) == [
        ref, Checkpoint(),
        Move(Pose(10, 20, 180), {"a": 1.0}), Expose(), Checkpoint(),
        Move(Pose(30, 20, 180), {"a": 2.0}), Expose(), Checkpoint(),
        ref, Checkpoint(),
        Move(Pose(50, 20, 180), {"a": 3.0}), Expose(), Checkpoint(),
        ref,
    ]
    assert count_rows(list(sweep_steps(sweep, bracket=(0.5, 2)))) == 2 + 3 * 2


def test_bracket_custom_dark_and_replay_skip_done_work(
    tmp_path: Path, rig_sim_path: Path, plan_path: Path
) -> None:
    engine, rig = _engine(tmp_path, rig_sim_path, plan_path)
    called: list[int] = []
    plan = [
        Reference(),
        Move(Pose(30, 30, 180)),
        Expose(bracket=(0.25, 1.0, 4.0)),
        Dark(),
        Custom("note", lambda ctx: called.append(ctx.step)),
        Checkpoint(),
        Move(Pose(30, 40, 180)),
        Expose(),
    ]
    counts = engine.run(plan)
    assert counts == {"done": 1 + 3 + 1 + 1 + 1}
    assert called == [5]
    assert rig.kinds().count("move") == 3  # reference, two poses: the bracket shares one move
    exposures = [c[1][0] for c in rig.calls if c[0] == "capture"]
    base = engine.rig.camera.exposure_s
    assert exposures == pytest.approx([base, base / 4, base, base * 4, base, base])
    assert ("light", False) in rig.calls and rig.calls[-1][0] == "capture"
    with Journal(engine.folder.path / JOURNAL_FILE) as j:
        recs = list(j.steps())
    assert [r.kind for r in recs] == ["reference", "pose", "pose", "pose", "dark", "custom", "pose"]
    assert [r.note for r in recs][1:4] == ["bracket=0.25", "bracket=1", "bracket=4"]

    # Replaying the finished plan does nothing at all: no move, no frame, no call.
    rig.calls.clear()
    assert engine.run(plan) == counts
    assert rig.calls == [] and called == [5]


def test_replay_retakes_only_missing_frame_and_moves_only_there(
    tmp_path: Path, rig_sim_path: Path, plan_path: Path
) -> None:
    engine, rig = _engine(tmp_path, rig_sim_path, plan_path)
    plan = [Reference(), Move(Pose(30, 30, 180)), Expose(), Move(Pose(30, 40, 180)), Expose()]
    engine.run(plan)
    first = (engine.folder.frames_dir / "step-000002.dng").read_bytes()
    (engine.folder.frames_dir / "step-000002.dng").write_bytes(b"bit rot")
    partial_name(engine.folder.frames_dir / "step-000003.dng").write_bytes(b"half")
    rig.calls.clear()
    engine.run(plan)
    assert rig.kinds() == ["present", "move", "capture"]  # only the damaged step's pose
    assert (engine.folder.frames_dir / "step-000002.dng").read_bytes() == first
    assert not [p for p in engine.folder.frames_dir.iterdir() if is_partial(p)]
    with Journal(engine.folder.path / JOURNAL_FILE) as j:
        assert any("fails its SHA-256" in e[3] for e in j.events())


def test_changed_plan_is_refused(tmp_path: Path, rig_sim_path: Path, plan_path: Path) -> None:
    engine, _ = _engine(tmp_path, rig_sim_path, plan_path)
    engine.run([Reference(), Move(Pose(30, 30, 180)), Expose()])
    with pytest.raises(SessionError, match="plan step 1 is a pose .* journal holds a pose"):
        engine.run([Reference(), Move(Pose(30, 40, 180)), Expose()])

    def fail(ctx: object) -> None:
        raise RuntimeError("script bug")

    with pytest.raises(RuntimeError):
        engine.run([Reference(), Move(Pose(30, 30, 180)), Expose(), Custom("x", fail)])
    with pytest.raises(SessionError, match="plan ended before journal step 2"):
        engine.run([Reference(), Move(Pose(30, 30, 180)), Expose()])


def test_stop_request_stops_at_next_checkpoint(
    tmp_path: Path, rig_sim_path: Path, plan_path: Path
) -> None:
    engine, rig = _engine(tmp_path, rig_sim_path, plan_path)
    seen: list[str] = []

    class StopAfterFirstPose(Observer):
        def step(self, event: Any) -> None:
            seen.append(event.record.kind)
            if event.record.kind == "pose":
                engine.request_stop()

    engine.observers = [StopAfterFirstPose()]
    plan = [Reference(), Checkpoint(), Move(Pose(30, 30, 180)), Expose(), Checkpoint("pose 1"),
            Move(Pose(30, 40, 180)), Expose()]
    with pytest.raises(SafetyStop, match="stopped at a checkpoint before step 2"):
        engine.run(plan)
    assert seen == ["reference", "pose"]
    engine.observers = []
    assert engine.run(plan) == {"done": 3}
    assert rig.kinds().count("capture") == 3


def test_expose_without_move_and_unknown_step(tmp_path: Path, rig_sim_path: Path,
                                              plan_path: Path) -> None:
    engine, _ = _engine(tmp_path, rig_sim_path, plan_path)
    with pytest.raises(SessionError, match="Expose before any Move"):
        engine.run([Expose()])
    with pytest.raises(SessionError, match="unknown plan step"):
        engine.run(["move somewhere"])  # type: ignore[list-item]


def test_scripted_session_on_simulated_rig_with_live_reduction(
    tmp_path: Path, rig_sim_path: Path, plan_path: Path
) -> None:
    live = LiveReduction()
    events: list[int] = []
    with api.scripted_session(tmp_path / "live", rig_sim_path, plan_path,
                              material="lambert:albedo=0.5", seed=2) as s:
        steps = s.sweep()
        counts = s.run(steps, observers=[live, CallbackObserver(lambda e: events.append(e.done))])
    assert counts == {"done": 4}  # reference, 2 poses, reference
    assert events == [1, 2, 3, 4]
    assert live.table is not None and live.table.n_samples == 2
    np.testing.assert_allclose(live.table.mean[live.table.count > 0], 0.5 / np.pi, rtol=0.03)
    # The final reduction of the same frames agrees with the live estimate.
    red = api.reduce(tmp_path / "live").table
    np.testing.assert_allclose(red.mean[red.count > 0], live.table.mean[live.table.count > 0],
                               rtol=0.02)
    with pytest.raises(SessionError, match="scripted session"):
        api.resume(tmp_path / "live")
