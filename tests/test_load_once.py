"""A run loads its rig and plan files once and builds its planner once."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from conftest import EXAMPLES, TINY_PLAN_ARGS, grid_plan_text

import acquisition.config.plan as plan_mod
import acquisition.config.rig as rig_mod
from acquisition import api
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
