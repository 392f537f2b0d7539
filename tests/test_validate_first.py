"""Validate before acting: whatever the rig, plan and options allow to check is checked before a
session folder is created or a byte is sent, and refused in one line naming the cause and fix.

Each case here failed on the code before this check existed (a folder left behind, a silent
pass, a late failure in ``reduce``, exit status 0)."""

from __future__ import annotations

import math
import re
import types
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, TINY_PLAN_ARGS, grid_plan_text

from acquisition import api
from acquisition.cli import main
from acquisition.config.plan import UnitsWarning, load_plan
from acquisition.config.rig import load_rig
from drivers.errors import ConfigError, SessionError

RIG = EXAMPLES / "rig-sim.toml"
LIGHT_STAGE = EXAMPLES / "rig-lightstage-sim.toml"


def edited(src: Path, tmp_path: Path, *changes: tuple[str, str], name: str | None = None) -> Path:
    text = src.read_text()
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new, 1)
    out = tmp_path / (name or src.name)
    out.write_text(text)
    return out


@pytest.fixture
def tiny_plan(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    return path


def pose_array(plan: object) -> np.ndarray:
    return np.array([p.as_tuple() for p in plan.poses()])  # type: ignore[attr-defined]


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith("gonio: error:")]
    assert len(lines) == 1, err
    return lines[0]


# ---------------------------------------------------------------------- fault specs
@pytest.mark.parametrize(("fault", "match"), [
    ("bogus", r"fault spec 'bogus': 'bogus' is not key=value"),
    ("overload:id=9,after=1", r"--sim-fault overload:id=9,after=1 names servo ID 9, which no "
                              r"simulated bus has: use one of IDs 1, 2, 3"),
])
def test_capture_refuses_a_bad_fault_spec_before_creating_the_folder(
        tmp_path: Path, tiny_plan: Path, capsys: pytest.CaptureFixture[str], fault: str,
        match: str) -> None:
    out = tmp_path / "s"
    assert main(["capture", "--rig", str(RIG), "--plan", str(tiny_plan), "--out", str(out),
                 "--sim-fault", fault]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert re.search(match, line), line
    assert not out.exists()
    # the rerun with a good spec is not stopped by "already exists"
    assert main(["capture", "--rig", str(RIG), "--plan", str(tiny_plan), "--out", str(out),
                 "--sim-fault", "delay=1"]) == 0


def test_scripted_session_refuses_a_bad_fault_spec_before_creating_the_folder(
        tmp_path: Path, tiny_plan: Path) -> None:
    out = tmp_path / "s"
    with pytest.raises(ConfigError, match="fault spec 'drop=2'"), api.scripted_session(
            out, RIG, tiny_plan, sim_faults=["drop=2"]):
        pass
    assert not out.exists()


def real_servo_rig(tmp_path: Path) -> Path:
    """rig-sim.toml on real hardware: a real bus and a gphoto2 camera."""
    return edited(RIG, tmp_path, ("simulated = true", "simulated = false"),
                  ('port = "sim"', 'port = "/dev/gonio-no-such-port"'),
                  ('driver = "simulated"', 'driver = "gphoto2"'), name="rig-real.toml")


def test_sim_fault_on_a_rig_without_a_simulated_bus_is_refused(tmp_path: Path,
                                                               tiny_plan: Path) -> None:
    rig = real_servo_rig(tmp_path)
    out = tmp_path / "s"
    with pytest.raises(ConfigError, match=r"--sim-fault drop=0.1 needs a simulated servo bus and "
                                          r"this rig has none \(its \[buses\] are real"):
        api.capture(rig, tiny_plan, out, sim_faults=["drop=0.1"], prompt=lambda target: None)
    assert not out.exists()
    # the console refuses them too, before it opens the (real) port
    with pytest.raises(ConfigError, match="needs a simulated servo bus"), api.open_console(
            rig, sim_faults=["drop=0.1"]):
        pass


def test_capture_checks_the_camera_before_creating_the_folder(tmp_path: Path,
                                                              tiny_plan: Path) -> None:
    out = tmp_path / "s"
    rig = real_servo_rig(tmp_path)
    with pytest.raises(ConfigError, match="no one to ask"):
        api.capture(rig, tiny_plan, out)  # a real camera and no operator prompt
    assert not out.exists()
    sim_camera = edited(RIG, tmp_path, ("simulated = true", "simulated = false"),
                        name="rig-mixed.toml")
    with pytest.raises(ConfigError, match="simulated camera renders from the simulator"):
        api.capture(sim_camera, tiny_plan, out)
    assert not out.exists()


# ---------------------------------------------------------------------- rig kind vs command
def test_capture_refuses_a_light_stage_rig(tmp_path: Path, tiny_plan: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"  # plan-quick has a pose the light stage "reaches": a folder was made
    assert main(["capture", "--rig", str(LIGHT_STAGE), "--plan", str(EXAMPLES / "plan-quick.toml"),
                 "--out", str(out)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "is a light-stage rig" in line and "gonio lightstage capture --rig" in line
    assert not out.exists()
    assert main(["plan", str(tiny_plan), "--rig", str(LIGHT_STAGE)]) == 2
    assert "gonio lightstage capture" in one_error_line(capsys.readouterr().err)
    with pytest.raises(ConfigError, match="light-stage rig"), api.scripted_session(
            out, LIGHT_STAGE, tiny_plan):
        pass
    assert not out.exists()


def test_lightstage_capture_refuses_a_servo_rig_pointing_at_gonio_capture(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    assert main(["lightstage", "capture", "--rig", str(RIG), "--out", str(out)]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "not a light stage" in line and f"gonio capture --rig {RIG}" in line
    assert not out.exists()


# ---------------------------------------------------------------------- ROI inside the sensor
@pytest.mark.parametrize(("roi", "match"), [
    ("[40, 8, 60, 24]", r"\[camera\] roi: \[40, 8, 60, 24\] reaches beyond the simulated "
                        r"sensor's 48×32 superpixels"),
    ("[12, 8, 36, 33]", r"reaches beyond the simulated sensor's 48×32"),
    ("[-2, 8, 36, 24]", r"\[camera\] roi: must be .* 0 ≤ x0 < x1"),
    ("[36, 8, 12, 24]", r"\[camera\] roi: must be .* 0 ≤ x0 < x1"),
])
def test_roi_outside_the_simulated_sensor_is_refused_at_load(
        tmp_path: Path, tiny_plan: Path, capsys: pytest.CaptureFixture[str], roi: str,
        match: str) -> None:
    rig = edited(RIG, tmp_path, ("roi = [12, 8, 36, 24]", f"roi = {roi}"))
    with pytest.raises(ConfigError, match=match):
        load_rig(rig)
    assert main(["plan", str(tiny_plan), "--rig", str(rig)]) == 2
    capsys.readouterr()
    assert main(["capture", "--rig", str(rig), "--plan", str(tiny_plan),
                 "--out", str(tmp_path / "s")]) == 2
    assert "roi" in one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "s").exists()


def test_roi_fits_exactly_at_the_sensor_edge(tmp_path: Path) -> None:
    rig = load_rig(edited(RIG, tmp_path, ("roi = [12, 8, 36, 24]", "roi = [0, 0, 48, 32]")))
    assert rig.camera.roi == (0, 0, 48, 32)


def test_real_camera_roi_is_checked_against_the_first_frame(tmp_path: Path) -> None:
    from acquisition.devices.rig import RigDevices
    from simulators.camera import SimCamera
    from simulators.sensor import SensorModel

    frame = tmp_path / "frame.dng"
    SimCamera(SensorModel(width=32, height=32), lambda: np.full(3, 1.0)).capture(frame, 0.01)
    rig = load_rig(real_servo_rig(tmp_path))  # ROI [12, 8, 36, 24]: beyond 16 × 16
    with pytest.raises(ConfigError, match=r"\[camera\] roi \[12, 8, 36, 24\] reaches beyond the "
                                          r"camera's 16×16 superpixels"):
        RigDevices.roi_saturated(types.SimpleNamespace(rig=rig), frame)  # type: ignore[arg-type]
    inside = load_rig(edited(real_servo_rig(tmp_path), tmp_path,
                             ("roi = [12, 8, 36, 24]", "roi = [2, 2, 14, 14]")))
    assert RigDevices.roi_saturated(types.SimpleNamespace(rig=inside), frame) is False  # type: ignore[arg-type]


# ---------------------------------------------------------------------- units
RADIAN_GRID = """format_version = 1
name = "rad"
{units}
[sampling]
kind = "grid"
theta_i = {{ start = 0, stop = 1.3, step = 0.26 }}
theta_r = {{ start = 0, stop = 1.3, step = 0.26 }}
delta_phi = {{ start = 0, stop = 3.14, step = 0.52 }}
"""


def test_a_radian_plan_read_as_degrees_warns_and_plan_exits_non_zero(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = tmp_path / "rad.toml"
    plan.write_text(RADIAN_GRID.format(units=""))
    with pytest.warns(UnitsWarning, match=r'every angle lies within ±2π .* set units = "rad"'):
        load_plan(plan)
    assert main(["plan", str(plan), "--rig", str(RIG)]) == 2
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if line.startswith("gonio: warning:")]
    assert len(warning) == 1 and 'units = "rad"' in warning[0]
    line = one_error_line(err)
    assert f"plan {plan} leaves no measurable pose on this rig (" in line
    assert "arm-collision" in line and "check its units and ranges" in line
    with pytest.raises(SessionError, match="leaves no measurable pose"), pytest.warns(UnitsWarning):
        api.plan_sweep(plan, RIG)


def test_units_rad_converts_every_angle(tmp_path: Path) -> None:
    rad = tmp_path / "rad.toml"
    rad.write_text(RADIAN_GRID.format(units='units = "rad"'))
    deg = tmp_path / "deg.toml"
    deg.write_text(grid_plan_text(*[(0, math.degrees(v1), math.degrees(v2)) for v1, v2 in
                                    ((1.3, 0.26), (1.3, 0.26), (3.14, 0.52))]))
    a, b = load_plan(rad), load_plan(deg)
    assert a.units == "rad" and b.units == "deg"
    np.testing.assert_allclose(pose_array(a), pose_array(b))
    np.testing.assert_allclose(a.table.theta_i_edges, b.table.theta_i_edges)
    assert len(api.plan_sweep(rad, RIG).steps) == len(api.plan_sweep(deg, RIG).steps) > 0


def test_units_rad_in_lists_csv_bins_specular_uniform_and_constraints(tmp_path: Path) -> None:
    (tmp_path / "poses.csv").write_text("theta_i,theta_r,delta_phi\n0.5236,0.7854,3.1416\n")
    head = 'format_version = 1\nunits = "rad"\n'
    cases = {
        "list": '[sampling]\nkind = "list"\nbin_deg = 0.08727\n'
                "poses = [[0.5236, 0.7854, 3.1416], [1.5708, 0, -3.1416]]\n"
                "[constraints]\nshadow_cone_deg = 0.1396\nmax_elevation_deg = 1.4835\n",
        "csv": '[sampling]\nkind = "list"\ncsv = "poses.csv"\n',
        "specular": '[sampling]\nkind = "specular"\nstep_deg = 0.17453\nmin_step_deg = 0.04363\n'
                    "theta_i = { start = 0.5236, stop = 0.5236, step = 0.1 }\n"
                    "max_theta_r_deg = 1.3963\n",
        "uniform": '[sampling]\nkind = "uniform"\nlight_count = 3\ncamera_count = 5\n'
                   "max_theta_deg = 1.0472\n",
    }
    plans = {}
    for name, body in cases.items():
        path = tmp_path / f"{name}.toml"
        path.write_text(head + body)
        plans[name] = load_plan(path)
    lst = pose_array(plans["list"])
    np.testing.assert_allclose(lst, [[30, 45, 180], [90, 0, -180]], atol=1e-3)  # π/2 → 90
    assert plans["list"].table.theta_i_edges[1] == pytest.approx(5.0, abs=1e-3)
    assert plans["list"].shadow_cone_deg == pytest.approx(8.0, abs=1e-2)
    assert plans["list"].max_elevation_deg == pytest.approx(85.0, abs=1e-2)
    np.testing.assert_allclose(pose_array(plans["csv"]), [[30, 45, 180]], atol=1e-3)
    np.testing.assert_allclose(pose_array(plans["specular"])[:, 0], 30.0, atol=1e-3)
    assert max(p.theta_r for p in plans["specular"].poses()) <= 80.0 + 1e-2
    assert max(max(p.theta_i, p.theta_r) for p in plans["uniform"].poses()) <= 60.0 + 1e-2


def test_units_must_be_deg_or_rad(tmp_path: Path) -> None:
    path = tmp_path / "p.toml"
    path.write_text(RADIAN_GRID.format(units='units = "grad"'))
    with pytest.raises(ConfigError, match=r"top level units: must be one of deg, rad, got 'grad'"):
        load_plan(path)


def test_a_degree_plan_with_large_angles_does_not_warn(tmp_path: Path,
                                                       recwarn: pytest.WarningsRecorder) -> None:
    for name in ("plan-quick.toml", "plan-sphere.toml", "plan-coarse-specular.toml"):
        load_plan(EXAMPLES / name)
    path = tmp_path / "zeros.toml"  # all zero: nothing to tell degrees from radians by
    path.write_text('format_version = 1\n[sampling]\nkind = "list"\nposes = [[0, 0, 0]]\n')
    load_plan(path)
    assert not [w for w in recwarn if issubclass(w.category, UnitsWarning)]


def test_move_with_radian_looking_angles_warns(capsys: pytest.CaptureFixture[str]) -> None:
    main(["move", "--rig", str(RIG), "--theta-i", "0.5", "--theta-r", "0.5",
          "--delta-phi", "3.14"])
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if line.startswith("gonio: warning:")]
    assert len(warning) == 1, err
    assert "read as degrees" in warning[0] and "radians × 180/π" in warning[0]


@pytest.mark.parametrize(("poses", "match"), [
    ("[[-10, 30, 180], [20, 30, 180]]", r"pose 1 \[-10, 30, 180\] has θi = -10°, outside 0…90°"),
    ("[[20, 30, 180], [20, 95, 0]]", r"pose 2 \[20, 95, 0\] has θr = 95°, outside 0…90°"),
    ("[[20, 30, 400]]", r"pose 1 \[20, 30, 400\] has Δφ = 400°, outside -180…360°"),
    ("[[20, 30, nan]]", r"pose 1 \[20, 30, nan\] has Δφ = nan°"),
])
def test_list_poses_have_the_limits_of_a_grid(tmp_path: Path, poses: str, match: str) -> None:
    path = tmp_path / "list.toml"
    path.write_text(f'format_version = 1\n[sampling]\nkind = "list"\nreciprocal = "both"\n'
                    f"poses = {poses}\n")
    with pytest.raises(ConfigError, match=r"list.toml: \[sampling\] poses: " + match):
        load_plan(path)


def test_csv_poses_have_the_limits_of_a_grid(tmp_path: Path) -> None:
    (tmp_path / "poses.csv").write_text("theta_i,theta_r,delta_phi\n20,30,180\n-10,30,0\n")
    path = tmp_path / "csv.toml"
    path.write_text('format_version = 1\n[sampling]\nkind = "list"\ncsv = "poses.csv"\n')
    with pytest.raises(ConfigError, match=r"\[sampling\] csv: pose 2 \[-10, 30, 0\] has θi = -10°"):
        load_plan(path)


def test_resume_of_a_light_stage_session_refuses_sim_faults(tmp_path: Path) -> None:
    """A light stage has no servo bus: the fault would be ignored, so it is refused."""
    from acquisition.lightstage.capture import DEFAULT_PLAN, META_KEY
    from acquisition.session.folder import SessionFolder, create_session

    plan = tmp_path / "plan.toml"
    plan.write_text(DEFAULT_PLAN)
    create_session(tmp_path / "ls", LIGHT_STAGE, plan, material=None, scripted=True)
    with SessionFolder(tmp_path / "ls").journal() as journal:
        journal.set_meta(META_KEY, {"sequences": ["olat"], "white": True, "dark": True})
    with pytest.raises(ConfigError, match=r"--sim-fault drop=0.1 needs a simulated servo bus and "
                                          r"this rig has none \(a light stage has no servo bus\)"):
        api.resume(tmp_path / "ls", sim_faults=["drop=0.1"])
    with SessionFolder(tmp_path / "ls").journal(readonly=True) as journal:
        assert not list(journal.steps())  # nothing ran
