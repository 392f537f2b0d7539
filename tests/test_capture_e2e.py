"""End to end on the simulated rig: real SDK on a pty, real DNG files through rawpy."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import SMALL_PLAN, grid_plan_text

from acquisition import api
from acquisition.api.truth import relative_errors, truth_table
from acquisition.cli import main
from acquisition.session.folder import JOURNAL_FILE
from acquisition.session.journal import Journal
from acquisition.tables import IsotropicTable
from drivers.errors import SafetyStop, SessionError

SPECULAR_PLAN = grid_plan_text((20, 60, 20), (20, 60, 20), (90, 180, 45), name="specular")


@pytest.fixture
def small_plan(tmp_path: Path) -> Path:
    path = tmp_path / "plan-small.toml"
    path.write_text(SMALL_PLAN)
    return path


def test_lambert_recovers_albedo_over_pi(rig_sim_path: Path, small_plan: Path, tmp_path: Path) -> None:
    out = tmp_path / "lambert"
    result = api.capture(rig_sim_path, small_plan, out, material="lambert:albedo=0.5", seed=3)
    sweep = api.plan_sweep(small_plan, rig_sim_path)
    assert len(sweep.steps) + len(sweep.rejected) == 27
    assert result.counts == {"done": len(sweep.steps) + 2}  # + white reference first and last
    reduction = api.reduce(out)
    table = IsotropicTable.load_h5(out / "brdf.h5")
    measured = table.mean[table.count > 0]
    rel = np.abs(measured - 0.5 / np.pi) / (0.5 / np.pi)
    assert np.median(rel) <= 0.02
    assert reduction.frames == len(sweep.steps)
    with h5py.File(out / "brdf.h5") as f:
        assert f.attrs["units"] == "1/sr" and f.attrs["quantity"] == "brdf"
        assert f["mean"].shape[-1] == 3 and f["count"].dtype == np.int64


def test_ggx_maximum_is_specular(rig_sim_path: Path, tmp_path: Path) -> None:
    plan = tmp_path / "plan-spec.toml"
    plan.write_text(SPECULAR_PLAN)
    out = tmp_path / "ggx"
    api.capture(rig_sim_path, plan, out, material="ggx:albedo=0.2,alpha=0.3,f0=0.04", seed=4)
    table = api.reduce(out).table
    g = np.where(table.count > 0, table.mean[..., 1], -np.inf)
    i, j, k = np.unravel_index(int(np.argmax(g)), g.shape)
    ti, tr, dp = table.centers()
    assert ti[i] == tr[j] and dp[k] == 180
    assert np.median(relative_errors(table, truth_table(out))) < 0.03


def test_interrupted_capture_resumes_to_identical_table(
    rig_sim_path: Path, small_plan: Path, tmp_path: Path
) -> None:
    whole = tmp_path / "whole"
    api.capture(rig_sim_path, small_plan, whole, material="lambert:albedo=0.3", seed=9)

    cut = tmp_path / "cut"

    def interrupt_at_ten(done: int, total: int, record: object) -> None:
        if done == 10:
            raise KeyboardInterrupt

    with pytest.raises(SafetyStop, match="gonio resume"):
        api.capture(rig_sim_path, small_plan, cut, material="lambert:albedo=0.3", seed=9,
                    progress=interrupt_at_ten)
    with Journal(cut / JOURNAL_FILE) as j:
        assert j.counts()["done"] == 10
    api.resume(cut)
    with Journal(cut / JOURNAL_FILE) as j:
        records = list(j.steps())
    assert all(r.status == "done" for r in records)
    assert len({r.frame for r in records}) == len(records)
    a, b = api.reduce(whole).table, api.reduce(cut).table
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.mean, b.mean)


def test_capture_refuses_existing_session(rig_sim_path: Path, small_plan: Path, tmp_path: Path) -> None:
    out = tmp_path / "exists"
    out.mkdir()
    (out / "keep.txt").write_text("operator data")
    with pytest.raises(SessionError, match="already exists"):
        api.capture(rig_sim_path, small_plan, out, material="lambert:albedo=0.5")
    assert (out / "keep.txt").read_text() == "operator data"


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ({"--material": "chalk:x=1"}, "unknown material 'chalk:x=1'"),
        ({"--plan": "missing.toml"}, "plan file missing.toml does not exist"),
    ],
)
def test_cli_errors_are_one_line(
    rig_sim_path: Path, small_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    override: dict[str, str], message: str,
) -> None:
    options = {"--rig": str(rig_sim_path), "--plan": str(small_plan),
               "--out": str(tmp_path / "s"), "--material": "lambert:albedo=0.5", **override}
    code = main(["capture", *[x for kv in options.items() for x in kv]])
    err = capsys.readouterr().err
    assert code != 0
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "s").exists()


def test_pose_outside_limits_is_refused(
    rig_sim_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(SMALL_PLAN.replace('kind = "grid"', 'kind = "list"\nposes = [[30, 89, 90]]')
                    .split("theta_i =")[0])
    code = main(["capture", "--rig", str(rig_sim_path), "--plan", str(plan),
                 "--out", str(tmp_path / "s"), "--material", "lambert:albedo=0.5"])
    err = capsys.readouterr().err
    assert code != 0 and "no measurable pose" in err and err.count("\n") == 1


def test_scripted_dark_frames_switch_the_simulated_lamp(rig_sim_path: Path, small_plan: Path,
                                                         tmp_path: Path) -> None:
    """A Dark step exposes with the lamp off; the reduction ignores it as a sample."""
    from acquisition.geometry.kinematics import Pose
    from acquisition.session.steps import Dark, Expose, Move, Reference
    from calibration.linearize import linearize, roi_mean
    from calibration.raw import load_raw

    out = tmp_path / "dark"
    with api.scripted_session(out, rig_sim_path, small_plan, material="lambert:albedo=0.5") as s:
        s.run([Reference(), Move(Pose(30, 30, 90)), Expose(), Dark(), Reference()])
    with Journal(out / JOURNAL_FILE) as j:
        rows = {r.kind: r for r in j.steps()}
    x0, y0, x1, y1 = 12, 8, 36, 24
    lit = roi_mean(linearize(load_raw(out / "frames" / rows["pose"].frame)), (x0, y0, x1 - x0, y1 - y0))
    dark = roi_mean(linearize(load_raw(out / "frames" / rows["dark"].frame)), (x0, y0, x1 - x0, y1 - y0))
    assert np.all(dark[0] < 0.02 * lit[0])
    table = api.reduce(out).table
    assert int(table.count.sum()) == 1
