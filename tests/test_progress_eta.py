"""The progress bar's ETA: per-step predictions from the planner's time model, corrected by the
run's own pace; checked on fake sequences, on a real session, and once through ``gonio capture``.
"""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

import pytest
from conftest import LIGHTSTAGE_RIG, TINY_PLAN_ARGS, grid_plan_text, unfinish
from tqdm import tqdm

from acquisition import api
from acquisition.cli import main, progress
from acquisition.cli.capture import eta_from_time_model
from acquisition.cli.progress import RunEta, format_eta
from acquisition.config.plan import load_plan
from acquisition.config.rig import load_rig
from acquisition.planning.planner import Planner
from acquisition.planning.timing import AxisProfile, StepCosts, TimeModel
from acquisition.session.folder import SessionFolder
from acquisition.session.journal import StepRecord
from acquisition.session.steps import CUSTOM, POSE, REFERENCE

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
RIG = EXAMPLES / "rig-sim.toml"
PLAN = """
format_version = 1
name = "eta"
[sampling]
kind = "list"
poses = [[10, 30, 180], [30, 50, 120], [50, 20, 60], [20, 60, 150], [60, 40, 90]]
"""


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_eta_is_remaining_prediction_times_the_runs_pace() -> None:
    clock = FakeClock()
    eta = RunEta({3: 1.0, 4: 2.0, 5: 3.0}, clock=clock)
    assert eta.scale == 1.0 and eta.eta_s() == pytest.approx(6.0)  # nothing done: rig time
    clock.t += 0.1
    eta.step_done(3)  # 1 s predicted took 0.1 s: a simulated rig, 10× faster
    assert eta.scale == pytest.approx(0.1)
    assert eta.eta_s() == pytest.approx(5.0 * 0.1)
    clock.t += 0.5
    eta.step_done(4)
    eta.step_done(4)  # repeated (a redone step) and unknown steps change nothing
    eta.step_done(99)
    assert eta.scale == pytest.approx(0.6 / 3.0)
    assert eta.eta_s() == pytest.approx(3.0 * 0.2)
    clock.t += 7.0
    eta.step_done(5)
    assert eta.predicted_left_s == 0.0 and eta.eta_s() == 0.0


def test_eta_on_a_slower_than_predicted_run() -> None:
    clock = FakeClock()
    eta = RunEta({k: 2.0 for k in range(10)}, clock=clock)
    for k in range(4):
        clock.t += 3.0  # every step takes 1.5× its prediction
        eta.step_done(k)
    assert eta.eta_s() == pytest.approx(6 * 2.0 * 1.5)


def test_format_eta() -> None:
    assert format_eta(0.4) == "ETA 0:00"
    assert format_eta(65) == "ETA 1:05"
    assert format_eta(3 * 3600 + 62) == "ETA 3:01:02"
    assert format_eta(-3) == "ETA 0:00"


def record(step: int, kind: str, joints: dict[str, float], note: str | None = None
           ) -> StepRecord:
    return StepRecord(step, kind, None, None, None, joints, "planned", 0, None, None, None,
                      None, None, None, None, None, note)


def test_predicted_step_s_moves_brackets_and_custom_steps() -> None:
    model = TimeModel({"a": AxisProfile(10.0, 100.0)},
                      StepCosts(settle_s=0.5, bus_cycle_s=0.25, exposure_s=0.1))
    start = {"a": 0.0}
    records = [
        record(0, REFERENCE, {"a": 0.0}),  # first step: a (zero) move anyway
        record(1, POSE, {"a": 20.0}, "bracket=0.5"),  # 2 s at 10 °/s + 0.1 s ramp
        record(2, POSE, {"a": 20.0}, "bracket=4"),  # same joints: exposure only
        record(3, CUSTOM, {}),
        record(4, POSE, {"a": 20.0 + 1e-12}),  # same joints within 1e-9
    ]
    got = api.predicted_step_s(records, model, start)
    assert got == pytest.approx({
        0: 0.75 + 0.1,
        1: model.move_s({"a": 0.0}, {"a": 20.0}) + 0.75 + 0.05,
        2: 0.4,
        3: 0.0,
        4: 0.1,
    })
    assert model.move_s({"a": 0.0}, {"a": 20.0}) == pytest.approx(2.1)


def test_session_predictions_add_up_to_the_estimate_and_the_run(tmp_path: Path) -> None:
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(PLAN)
    rig, plan = load_rig(RIG), load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    opened: list[dict[int, float]] = []
    result = api.capture(RIG, plan_path, tmp_path / "s", material="lambert:albedo=0.5",
                         on_open=lambda folder, _t: opened.append(api.step_durations(folder)))
    (before,) = opened
    assert sorted(before) == list(range(7))  # every step pending when the devices opened
    everything = api.step_durations(tmp_path / "s", pending_only=False)
    assert everything == pytest.approx(before)
    assert api.step_durations(tmp_path / "s") == {}  # all done now
    total = sum(everything.values())
    assert total == pytest.approx(sweep.estimated_s, rel=0.01)
    assert result.device_seconds is not None
    assert total == pytest.approx(result.device_seconds, rel=0.05)


def test_capture_bar_shows_the_time_model_eta(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(progress, "DISABLE", False)  # draw the bar although stderr is no tty
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(PLAN)
    out = tmp_path / "s"
    assert main(["capture", "--rig", str(RIG), "--plan", str(plan_path), "--out", str(out),
                 "--material", "lambert:albedo=0.5"]) == 0
    captured = capsys.readouterr()
    err = captured.err
    assert "poses planned" in captured.out and "estimated" in captured.out  # before moving
    frames = [f for f in err.replace("\r", "\n").splitlines() if f.startswith("capture:")]
    assert frames and all("ETA " in f for f in frames[1:]), frames
    assert "7/7" in frames[-1] and frames[-1].rstrip().endswith("ETA 0:00]")
    assert "s/step" not in frames[-1] and "step/s" not in frames[-1]  # not tqdm's rate ETA


def bar_lines(err: str, desc: str) -> list[str]:
    """The frames a tqdm bar called ``desc`` drew on stderr."""
    return [f for f in err.replace("\r", "\n").splitlines() if f.startswith(f"{desc}:")]


def test_resume_prints_the_remaining_estimate(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(progress, "DISABLE", False)
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    out = tmp_path / "s"
    api.capture(RIG, plan_path, out, material="lambert:albedo=0.5")
    left = unfinish(out, 2)  # as an interrupted run leaves them
    predicted = api.step_durations(out)
    assert sorted(predicted) == sorted(left)
    assert main(["resume", str(out)]) == 0
    captured = capsys.readouterr()
    minutes = sum(predicted.values()) / 60
    assert f"2 steps left; estimated {minutes:.1f} min of rig time" in captured.out
    frames = bar_lines(captured.err, "resume")
    assert frames and all("ETA " in f for f in frames[1:]), frames
    assert main(["resume", str(out), "--json"]) == 0  # --json: one JSON object, no estimate
    assert "steps left" not in capsys.readouterr().out


def test_lightstage_bar_eta_derives_from_its_estimate(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(progress, "DISABLE", False)
    for name in ("capture_lightstage", "plan_lightstage"):  # 9 frames, not 156 white + dark more
        monkeypatch.setattr(api, name, partial(getattr(api, name), white=False, dark=False))
    out = tmp_path / "l"
    assert main(["lightstage", "capture", "--rig", str(LIGHTSTAGE_RIG), "-o", str(out),
                 "--sequence", "sh", "--material", "lambert:albedo=0.5"]) == 0
    captured = capsys.readouterr()
    estimate = api.plan_lightstage(LIGHTSTAGE_RIG, ["sh"])
    assert estimate.frames == 9
    assert f"estimated {estimate.total_s:.1f} s of rig time" in captured.out
    frames = bar_lines(captured.err, "capture")
    assert frames and all("ETA " in f for f in frames[1:]), frames
    n = estimate.frames
    assert f"{n}/{n}" in frames[-1] and frames[-1].rstrip().endswith("ETA 0:00]")
    # the bar's predictions: one per journal step (frame), adding up to the estimate
    predicted = api.step_durations(out, pending_only=False)
    assert sorted(predicted) == list(range(n))
    assert sum(predicted.values()) == pytest.approx(estimate.total_s, rel=1e-9)
    bar = progress.StepBar(tqdm(disable=True))
    eta_from_time_model(bar, argparse.Namespace(json=False), announce=False)(SessionFolder(out), None)
    assert bar.eta is not None and bar.eta.predicted_left_s == 0.0  # all done
    left = unfinish(out, 3)
    assert main(["lightstage", "resume", str(out)]) == 0
    captured = capsys.readouterr()
    minutes = sum(predicted[k] for k in left) / 60
    assert f"3 steps left; estimated {minutes:.1f} min of rig time" in captured.out
    assert f"{n} steps done" in captured.out
    frames = bar_lines(captured.err, "resume")
    assert frames and all("ETA " in f for f in frames[1:]), frames
