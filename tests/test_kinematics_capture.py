"""The coaxial kinematics through a whole simulated capture: the simulated camera renders from
``forward_geometry`` of the true joints, the reduction bins at the commanded poses; a Lambertian
sample must come out as albedo/π in every bin."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition import api
from acquisition.tables import IsotropicTable

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

PLAN = """
format_version = 1
name = "coaxial-small"
[sampling]
kind = "grid"
theta_i = { start = 10, stop = 70, step = 30 }
theta_r = { start = 10, stop = 70, step = 30 }
delta_phi = { start = 0, stop = 180, step = 60 }
"""


@pytest.mark.slow
def test_coaxial_rig_captures_lambert(tmp_path: Path) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    out = tmp_path / "run"
    result = api.capture(EXAMPLES / "rig-coaxial-sim.toml", plan, out,
                         material="lambert:albedo=0.5", seed=3)
    planned = len(api.plan_sweep(plan, EXAMPLES / "rig-coaxial-sim.toml").steps)
    assert planned >= 15 and result.counts == {"done": planned + 2}
    api.reduce(out)
    table = IsotropicTable.load_h5(out / "brdf.h5")
    measured = table.mean[table.count > 0]
    assert len(measured) >= 15
    assert np.median(np.abs(measured - 0.5 / np.pi) / (0.5 / np.pi)) < 0.02
