"""A run loads its rig and plan files once and builds its planner once."""

from __future__ import annotations

import json
from collections import Counter
from functools import partial
from pathlib import Path

import pytest
from conftest import EXAMPLES, TINY_PLAN_ARGS, grid_plan_text

import acquisition.config.plan as plan_mod
import acquisition.config.rig as rig_mod
from acquisition import api
from acquisition.cli import main, progress
from acquisition.planning.planner import Planner


@pytest.fixture
def counts(monkeypatch: pytest.MonkeyPatch) -> Counter:
    seen: Counter = Counter()
    for module, kind in ((rig_mod, "rig"), (plan_mod, "plan")):
        original = module.load_toml

        def counting(path, what, _original=original, _kind=kind):  # noqa: ANN001
            seen[_kind] += 1
            return _original(path, what)

        monkeypatch.setattr(module, "load_toml", counting)
    init = Planner.__init__

    def counting_init(self, *args, **kwargs) -> None:  # noqa: ANN001
        seen["planner"] += 1
        init(self, *args, **kwargs)

    monkeypatch.setattr(Planner, "__init__", counting_init)
    return seen


def test_capture_and_resume_load_and_plan_once(tmp_path: Path, counts: Counter) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    api.capture(EXAMPLES / "rig-sim.toml", plan, tmp_path / "s", material="lambert:albedo=0.5",
                progress=lambda d, t, r: None,
                on_open=lambda folder, _t: api.step_durations(folder))
    assert counts == {"rig": 1, "plan": 1, "planner": 1}
    counts.clear()
    api.resume(tmp_path / "s", on_open=lambda folder, _t: api.step_durations(folder))
    assert counts == {"rig": 1, "plan": 1, "planner": 1}  # the session's copies, once



def test_gonio_demo_loads_and_plans_once_and_shows_the_planner_eta(
        tmp_path: Path, counts: Counter, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Capture, reduction and truth table share the run's rig, plan and planner (the bar's
    ETA asks the same planner for its per-step predictions)."""
    plan = tmp_path / "plan.toml"
    plan.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    monkeypatch.setattr(api, "run_demo", partial(api.run_demo, plan=plan))  # four poses
    monkeypatch.setattr(progress, "DISABLE", False)  # draw the bar although stderr is no tty
    assert main(["demo", "-o", str(tmp_path / "demo"), "--json"]) == 0
    assert counts == {"rig": 1, "plan": 1, "planner": 1}
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert result["poses"] > 0 and result["measured_bins"] > 0 and Path(result["plot"]).is_file()
    frames = [f for f in captured.err.replace("\r", "\n").splitlines() if f.startswith("demo capture:")]
    assert frames and all("ETA " in f for f in frames[1:]), frames
    assert frames[-1].rstrip().endswith("ETA 0:00]")
