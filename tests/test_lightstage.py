"""Light stage end to end: DMX widgets on real ptys driven through DmxWidget/LightController,
a simulated camera rendering the LEDs the widget outputs, durable sessions, per-LED
calibration and the BRDF table of a GGX sphere captured one light at a time."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from acquisition import api
from acquisition.cli import main
from acquisition.config.rig import load_rig
from acquisition.config.stage import stage_config
from acquisition.geometry.kinematics import poses_from_directions
from acquisition.lightstage import capture as capture_mod
from acquisition.lightstage.capture import capture_lightstage, resume_lightstage
from acquisition.lightstage.devices import LightStageDevices, open_lightstage
from acquisition.lightstage.reduce import iter_lightstage_samples, led_calibration
from acquisition.lightstage.sequences import SEQUENCES, capture_steps, sequence_frames
from acquisition.session.engine import StepEvent
from acquisition.session.folder import SessionFolder
from acquisition.session.journal import StepRecord
from acquisition.session.observers import Observer
from acquisition.session.status import session_status
from acquisition.tables import IsotropicTable
from drivers.errors import CommunicationError, ConfigError, HardwareError, SafetyStop
from drivers.lights import DutyCycleLimit, DutyPolicy
from drivers.storage import is_partial
from simulators.materials import directions_from_angles, material_from_spec

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-lightstage-sim.toml"
GGX = "ggx:albedo=0.2,alpha=0.3,f0=0.04"


def rig_with_led_error(tmp_path: Path, error: float, seed: int = 3) -> Path:
    text = RIG.read_text()
    old = "led_intensity_error = 0.0"
    assert old in text
    text = text.replace(old, f"led_intensity_error = {error}").replace(
        "led_error_seed = 1", f"led_error_seed = {seed}")
    path = tmp_path / "rig-lightstage.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def olat_session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """156-LED OLAT of a GGX sphere with ±10 % per-LED intensity errors injected."""
    tmp = tmp_path_factory.mktemp("lightstage")
    rig = rig_with_led_error(tmp, 0.10)
    result = capture_lightstage(rig, tmp / "s", material=GGX, seed=5)
    return tmp / "s", result


def test_example_rig_is_a_156_led_dome_with_a_sphere() -> None:
    rig = load_rig(RIG)
    stage = stage_config(rig)
    assert len(stage) == 156 and rig.sample.shape == "sphere"
    assert stage.solid_angles_sr.sum() == pytest.approx(2 * np.pi)
    assert stage.simulated and len({f.universe for f in stage.fixtures}) == 1
    np.testing.assert_allclose(stage.led_gain, 1.0)  # no error unless the rig asks for one


def test_capture_journals_every_frame_and_meets_the_time_estimate(olat_session) -> None:
    path, result = olat_session
    folder = SessionFolder(path)
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
    assert result.counts == {"done": 156 + 1 + 156}
    kinds = [r.kind for r in records]
    assert kinds == ["reference"] * 156 + ["dark"] + ["pose"] * 156
    assert [r.joints_cmd for r in records[157:160]] == [{"light": 0.0}, {"light": 1.0},
                                                      {"light": 2.0}]
    assert all((folder.frames_dir / str(r.frame)).is_file() for r in records)
    # rig time follows the DMX model exactly: the simulated clock only moves in device waits
    assert result.device_seconds == pytest.approx(result.estimate.total_s, rel=1e-3)
    assert result.estimate.light_changes == 313


def test_olat_brdf_table_matches_the_ggx_material(olat_session) -> None:
    path, _ = olat_session
    red = api.reduce(path)  # `gonio reduce DIR` dispatches to the light-stage reducer
    assert (path / "brdf.h5").is_file() and red.frames == 156
    table = red.table
    sel = table.count >= 10
    assert sel.sum() > 1000
    material = material_from_spec(GGX)
    ti, tr, dp = table.centers()
    wi, wo = directions_from_angles(*(a[sel] for a in np.meshgrid(ti, tr, dp, indexing="ij")))
    rel = np.abs(table.mean[sel] / material.eval_vectors(wi, wo) - 1)
    assert np.median(rel) < 0.05
    # the same samples' true values binned alike: radiometry alone, no bin-width effect
    folder = SessionFolder(path)
    plan = folder.plan()
    truth = IsotropicTable(plan.table.theta_i_edges, plan.table.theta_r_edges,
                           plan.table.delta_phi_edges)
    for fs in iter_lightstage_samples(path):
        a = poses_from_directions(fs.wi, fs.wo)
        truth.add(a[:, 0], a[:, 1], a[:, 2], material.eval_vectors(fs.wi, fs.wo))
    rel = table.mean[sel] / truth.mean[sel] - 1
    assert np.median(np.abs(rel)) < 0.02 and abs(np.median(rel)) < 0.01


def test_olat_tables_carry_an_uncertainty_and_fit_from_the_session_folder(olat_session) -> None:
    """Per-bin std_error from the sensor's noise, each LED's calibration noise and the
    binning term; `gonio fit SESSION` reduces a light-stage folder with its own reducer and
    recovers the material within its 1σ."""
    path, _ = olat_session
    fit = api.fit(path, "ggx")  # a session folder: reduced in memory
    table = api.open_table(path)
    measured = table.count > 0
    assert table.tracks_uncertainty and table.provenance["noise_model"] == "sensor model"
    assert np.isfinite(table.std_error[measured]).all() and (table.std_error[measured] > 0).all()
    assert 0.5 < fit.chi2_dof < 2.0
    truth = {"alpha": 0.3, "albedo": 0.2, "f0": 0.04}
    for name, value in truth.items():
        pull = (np.atleast_1d(fit.params[name]) - value) / np.atleast_1d(fit.sigma[name])
        assert np.all(np.abs(pull) < 5), (name, fit.params[name], fit.sigma[name])


def test_per_led_intensity_errors_are_calibrated_out(olat_session) -> None:
    path, _ = olat_session
    stage = stage_config(SessionFolder(path).rig())
    true_rel = stage.led_gain / stage.led_gain.mean()
    assert np.ptp(true_rel) > 0.15  # ±10 % really injected
    cal = led_calibration(path)
    assert (cal.pixels > 500).all()
    residual = cal.relative / true_rel[:, None] - 1
    assert np.max(np.abs(residual)) <= 0.01


def test_a_frame_is_exposed_only_under_the_commanded_settled_state(tmp_path: Path) -> None:
    rig = load_rig(RIG)
    with open_lightstage(rig, material=material_from_spec(GGX), seed=1) as dev:
        sim = dev.sims[1]
        for k in (0, 77, 155):
            levels = np.zeros(len(dev.stage))
            levels[k] = 1.0
            dev.set_levels(levels, hold_s=0.02)
            start = dev.clock.now()
            dev.capture(tmp_path / f"f{k}.dng", 0.02, 100, k)
            shown = sim.sim_states_during(start, start + 0.02)
            assert len(shown) == 1  # one state throughout the exposure ...
            assert shown[0][k] == 255 and sum(shown[0]) == 255  # ... the commanded one
        # a state commanded without waiting for it to settle is refused after the exposure
        dev.lights.olat(3, wait=False)
        with pytest.raises(HardwareError, match="not surely on"):
            dev.capture(tmp_path / "early.dng", 0.001, 100, 9)


def test_duty_cycle_limit_makes_leds_cool_down(tmp_path: Path) -> None:
    rig = load_rig(RIG)
    stage = dataclasses.replace(stage_config(rig),
                                duty=DutyCycleLimit(0.5, 1.0, DutyPolicy.WAIT))
    with open_lightstage(rig, material=material_from_spec(GGX), stage=stage) as dev:
        t0 = dev.clock.now()
        for i in range(4):
            dev.set_levels(np.ones(len(stage)), hold_s=0.3)
            dev.capture(tmp_path / f"on{i}.dng", 0.3, 100, i)
            assert dev.lights.duty_fraction("L000") <= 0.5 + 1e-6
        # 1.2 s on at ≤ 50 % over any 1 s: the LEDs had to wait
        assert dev.clock.now() - t0 > 1.7
        dev.lights.all_off()
        stage_raise = dataclasses.replace(stage, duty=DutyCycleLimit(0.5, 1.0))
    with open_lightstage(rig, material=material_from_spec(GGX), stage=stage_raise) as dev, \
            pytest.raises(Exception, match="duty budget"):
        dev.set_levels(np.ones(len(stage)), hold_s=0.6)


def test_sequences_are_data() -> None:
    stage = stage_config(load_rig(RIG))
    olat = sequence_frames(stage, "olat")
    assert len(olat) == 156 and all(sum(f.levels) == 1.0 and f.levels[f.light] == 1.0
                                    for f in olat)
    sh = sequence_frames(stage, "sh")
    assert len(sh) == 9 and all(min(f.levels) >= 0 and max(f.levels) <= 1 for f in sh)
    assert [f.pattern for f in sequence_frames(stage, "gradient")] == [
        "all-on", "gradient-x", "gradient-y", "gradient-z"]
    grad_z = np.array(sequence_frames(stage, "gradient")[3].levels)
    np.testing.assert_allclose(grad_z, 0.5 * (1 + stage.directions[:, 2]))
    assert sequence_frames(stage, "dark")[0].kind == "dark"
    steps = capture_steps(stage, ["all-on"])
    assert sum(1 for s in steps if hasattr(s, "levels")) == 156 + 1 + 1
    assert set(SEQUENCES) == {"olat", "all-on", "dark", "gradient", "sh"}
    with pytest.raises(ConfigError, match="unknown light-stage sequence"):
        sequence_frames(stage, "strobe")


def test_non_lightstage_rig_is_refused() -> None:
    with pytest.raises(ConfigError, match="not a light stage"):
        stage_config(load_rig(ROOT / "examples" / "rig-sim.toml"))


class _UnplugAfter(Observer):
    def __init__(self, devices: list[LightStageDevices], after: int) -> None:
        self.devices, self.after = devices, after

    def step(self, event: StepEvent) -> None:
        if event.done == self.after:
            self.devices[0].sims[1].sim_unplug()


def test_unplugged_widget_stops_cleanly_and_the_session_resumes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    opened: list[LightStageDevices] = []
    real_open = capture_mod.open_lightstage

    @contextmanager
    def spy(*args, **kwargs) -> Iterator[LightStageDevices]:  # noqa: ANN002, ANN003
        with real_open(*args, **kwargs) as dev:
            opened.append(dev)
            yield dev

    monkeypatch.setattr(capture_mod, "open_lightstage", spy)
    out = tmp_path / "s"
    with pytest.raises(CommunicationError, match="stopped responding") as err:
        capture_lightstage(RIG, out, sequences=["all-on"], material=GGX, seed=2,
                           observers=[_UnplugAfter(opened, 40)])
    assert "\n" not in str(err.value) and "USB cable" in str(err.value)
    assert f"gonio resume {out}" in str(err.value)
    folder = SessionFolder(out)
    with folder.journal(readonly=True) as journal:
        records: list[StepRecord] = list(journal.steps())
        events = journal.events()
    assert sum(r.status == "done" for r in records) == 40
    assert not any(r.status == "done" for r in records[40:])
    assert not [p for p in folder.frames_dir.iterdir() if is_partial(p)]
    assert any(e[1] == "error" and "stopped responding" in e[3] for e in events)
    first_frames = {r.frame: (folder.frames_dir / str(r.frame)).read_bytes()
                    for r in records if r.status == "done"}
    # resume through the generic `gonio resume` with a fresh (plugged-in) widget
    monkeypatch.undo()
    assert main(["resume", str(out)]) == 0
    assert "158 steps done" in capsys.readouterr().out
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
    assert len(records) == 158 and all(r.status == "done" for r in records)
    assert all((folder.frames_dir / name).read_bytes() == data  # done frames were kept
               for name, data in first_frames.items())
    assert (led_calibration(out).pixels > 0).all()
    assert len(list((out / "field").glob("light-*.exr"))) == 0  # no OLAT on the sample


def test_cli_capture_prints_estimate_and_errors(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["lightstage", "capture", "--rig", str(ROOT / "examples" / "rig-sim.toml"),
                 "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a light stage" in err
    assert not (tmp_path / "x").exists()
    with pytest.raises(SystemExit) as exit_:
        main(["lightstage", "capture", "--rig", str(RIG), "--out", str(tmp_path / "y"),
              "--sequence", "olat,strobe"])
    assert exit_.value.code == 2
    assert "unknown sequence 'strobe'" in capsys.readouterr().err


def test_resume_refuses_a_session_that_is_not_a_light_stage_one(tmp_path: Path) -> None:
    from acquisition.session.folder import create_session

    create_session(tmp_path / "g", ROOT / "examples" / "rig-sim.toml",
                   ROOT / "examples" / "plan-quick.toml", material=GGX)
    with pytest.raises(Exception, match="not a light-stage session"):
        resume_lightstage(tmp_path / "g")


class _CtrlCAfter(Observer):
    def __init__(self, after: int) -> None:
        self.after = after

    def step(self, event: StepEvent) -> None:
        if event.done == self.after:
            raise KeyboardInterrupt


def test_a_stopped_olat_reports_its_lights_its_progress_and_gonio_resume_ends_with_the_field(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    with pytest.raises(SafetyStop) as err:
        capture_lightstage(RIG, out, material=GGX, seed=4, observers=[_CtrlCAfter(83)])
    message = str(err.value)
    assert "every light switched off" in message and "axes" not in message
    status = session_status(out, drift=False, verify=False)
    steps = sum(1 for s in capture_steps(stage_config(load_rig(RIG)), ["olat"])
                if type(s).__name__ == "LightFrame")
    assert (status.done, status.total) == (83, steps) and steps > 300
    assert f"83/{steps} steps done" in "\n".join(status.lines())
    assert main(["resume", str(out)]) == 0  # the generic resume, as for a servo rig
    text = capsys.readouterr().out
    assert f"{steps} steps done" in text and "reflectance field: 156 EXRs" in text
    assert len(list((out / "field").glob("light-*.exr"))) == 156


def test_the_ctrl_c_notice_speaks_of_lights_on_a_light_stage() -> None:
    from acquisition import api

    assert "light" in api.LIGHTS_MESSAGE and "axes" not in api.LIGHTS_MESSAGE
    assert "axes" in api.FIRST_MESSAGE


def test_cli_olat_capture_and_resume_finish_with_the_field(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    assert main(["lightstage", "capture", "--rig", str(RIG), "-o", str(out), "--seed", "1"]) == 0
    text = capsys.readouterr().out
    assert "313 steps done" in text
    assert f"reflectance field: 156 EXRs in {out / 'field'}" in text
    assert main(["lightstage", "resume", str(out), "--json"]) == 0  # nothing left: reports
    payload = json.loads(capsys.readouterr().out)
    assert payload["counts"]["done"] == 313 and payload["field"]["images"] == 156
