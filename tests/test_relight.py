"""Reflectance fields and relighting: calibrated EXRs per light (OpenImageIO metadata), weights
from the lights' solid angles, and a relit GGX sphere against the simulator's direct render
under the same environment map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition.cli import main
from acquisition.config.rig import load_rig
from acquisition.config.stage import stage_config
from acquisition.formats.envmap import latlong_directions, read_exr, write_exr
from acquisition.lightstage.capture import capture_lightstage
from acquisition.lightstage.field import ReflectanceField, load_field, write_field
from acquisition.lightstage.relight import light_weights, relight
from acquisition.session.folder import SessionFolder
from acquisition.simworld.lightstage import render_environment
from simulators.materials import material_from_spec

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-lightstage-sim.toml"
GGX = "ggx:albedo=0.25,alpha=0.3,f0=0.04"


def environment(shape: tuple[int, int] = (32, 64)) -> np.ndarray:
    """A smooth sky: colour gradients plus a broad warm lobe (radiance, arbitrary units)."""
    d, _ = latlong_directions(shape)
    lobe = np.exp(6.0 * (d @ np.array([0.5, 0.3, 0.81]) - 1.0))
    return np.stack([1.0 + 0.8 * d[..., 0] + 3.0 * lobe, 1.0 + 0.5 * d[..., 1] + 2.0 * lobe,
                     0.6 + 0.4 * d[..., 2] + 0.5 * lobe], axis=-1)


@pytest.fixture(scope="module")
def field_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """OLAT of a GGX sphere with ±10 % per-LED intensity errors, and its reflectance field."""
    tmp = tmp_path_factory.mktemp("relight")
    rig = tmp / "rig.toml"
    rig.write_text(RIG.read_text().replace("led_intensity_error = 0.0",
                                           "led_intensity_error = 0.1"))
    capture_lightstage(rig, tmp / "s", material=GGX, seed=11)
    write_field(tmp / "s", tmp / "s" / "field")
    return tmp / "s"


def relative_rms(image: np.ndarray, reference: np.ndarray) -> float:
    on = reference.sum(axis=-1) > 0  # pixels on the lit sample
    return float(np.sqrt(np.mean((image[on] - reference[on]) ** 2))
                 / np.sqrt(np.mean(reference[on] ** 2)))


def test_light_weights_integrate_the_environment_over_the_dome() -> None:
    stage = stage_config(load_rig(RIG))
    env = environment((64, 128))
    w = light_weights(stage.directions, stage.solid_angles_sr, env)
    d, omega = latlong_directions(env.shape[:2])
    up = d[..., 2] > 0
    upper = (env[up] * omega[up][:, None]).sum(axis=0)
    np.testing.assert_allclose(w.sum(axis=0), upper, rtol=0.01)
    # a light's weight follows the environment around it, not the map's global mean
    zenith, low = 0, int(np.argmin(stage.directions[:, 2]))
    assert w[zenith, 2] / stage.solid_angles_sr[zenith] > w[low, 2] / stage.solid_angles_sr[low]
    # a map coarser than the dome: cells without pixels sample the map at the light
    coarse = light_weights(stage.directions, stage.solid_angles_sr, np.ones((4, 8, 3)))
    np.testing.assert_allclose(coarse, stage.solid_angles_sr[:, None] * np.ones(3))


def test_field_exrs_carry_light_direction_and_calibration(field_session: Path) -> None:
    field = load_field(field_session / "field")
    stage = stage_config(SessionFolder(field_session).rig())
    assert len(field) == 156 and field.images.shape[1:] == (64, 64, 3)
    np.testing.assert_array_equal(field.indices, np.arange(156))
    np.testing.assert_allclose(field.directions, stage.directions, atol=1e-6)
    np.testing.assert_allclose(field.solid_angles_sr, stage.solid_angles_sr, rtol=1e-6)
    _, attrs = read_exr(field_session / "field" / "light-077.exr")
    true_rel = stage.led_gain / stage.led_gain.mean()
    np.testing.assert_allclose(attrs["gonio:relative_intensity"], [true_rel[77]] * 3, rtol=0.01)
    assert len(attrs["gonio:calibration"]) == 3 and attrs["gonio:step"] == 157 + 77
    assert attrs["gonio:units"].startswith("sr^-1")


def test_relit_field_matches_a_direct_render_within_2_percent(field_session: Path) -> None:
    rig = SessionFolder(field_session).rig()
    stage = stage_config(rig)
    field = load_field(field_session / "field")
    env = environment()
    direct = render_environment(rig, stage.camera_dir, material_from_spec(GGX), env,
                                field.images.shape[1:3])
    relit = relight(field, env)
    assert relative_rms(relit, direct) <= 0.02
    # without the per-LED calibration the ±10 % LED errors show in the relit image
    raw = ReflectanceField(field.images * (stage.led_gain / stage.led_gain.mean())[:, None, None,
                                                                                    None],
                           field.directions, field.solid_angles_sr, field.indices)
    assert relative_rms(relight(raw, env), direct) > relative_rms(relit, direct) + 0.002


def test_gonio_relight_writes_the_relit_exr(field_session: Path, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    env = environment()
    write_exr(tmp_path / "sky.exr", env)
    out = tmp_path / "relit.exr"
    assert main(["relight", str(field_session / "field"), "--env", str(tmp_path / "sky.exr"),
                 "-o", str(out)]) == 0
    assert "64 × 64" in capsys.readouterr().out
    image, attrs = read_exr(out)
    expected = relight(load_field(field_session / "field"), read_exr(tmp_path / "sky.exr")[0])
    np.testing.assert_allclose(image, expected, rtol=1e-5, atol=1e-7)
    assert attrs["gonio:lights"] == 156
    assert main(["relight", str(field_session / "field"), "--env", str(tmp_path / "none.exr"),
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot read image" in err
