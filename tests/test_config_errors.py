"""Malformed rig and plan files end in one-line ConfigErrors naming the file and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition.config.plan import load_plan
from acquisition.config.rig import load_rig
from drivers.errors import ConfigError, MaterialError
from simulators.materials import material_from_spec


def edited(src: Path, tmp_path: Path, old: str, new: str) -> Path:
    text = src.read_text()
    assert old in text
    out = tmp_path / src.name
    out.write_text(text.replace(old, new, 1))
    return out


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("min_deg = -87", "min_deg = 'low'", r"\[axes.light_theta\] min_deg: must be a number"),
        ("id = 2", "id = 1", r"\[axes.camera_theta\] id: 1 is already used by axis 'light_theta'"),
        ('bus = "main"', 'bus = "aux"', r"names bus 'aux'"),
        ("format_version = 1", "format_version = 9", r"format_version: is 9"),
        ('kinematics = "out-of-plane-arcs"', 'kinematics = "delta"', r"unknown 'delta'"),
        ("roi = [12, 8, 36, 24]", "roi = [12, 8]", r"\[camera\] roi"),
        ("max_deg = 87", "max_deg = 270", r"outside the servo's 0–4095"),
        ("settle_s = 0.05", "settle_s = 0.05\nsettle = 1", r"\[geometry\] settle: unknown key"),
        ("[light]", "[light", r"not valid TOML"),
    ],
)
def test_rig_errors(rig_sim_path: Path, tmp_path: Path, old: str, new: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        load_rig(edited(rig_sim_path, tmp_path, old, new))
    assert "\n" not in str(info.value)
    assert str(tmp_path) in str(info.value)


def test_missing_rig_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_rig(tmp_path / "nope.toml")


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ('kind = "grid"', 'kind = "spiral"', r"\[sampling\] kind: unknown 'spiral'"),
        ("step = 15 }", "step = 0 }", r"\[sampling.theta_i\] step: must be ≥"),
        ("stop = 75, step = 15 }", "stop = 95, step = 15 }", r"\[sampling.theta_i\] stop: must be ≤ 90"),
    ],
)
def test_plan_errors(plan_quick_path: Path, tmp_path: Path, old: str, new: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_plan(edited(plan_quick_path, tmp_path, old, new))


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("torrance:n=10", "unknown material"),
            ("phong:n=10", r"takes albedo, e, ks .*unknown: n; missing: albedo, e, ks"),
        ("lambert:albedo=x", "not a number"),
        ("ggx:albedo=0.2,alpha=0.3", "missing: f0"),
        ("lambert:albedo=2", r"\[0, 1\]"),
    ],
)
def test_material_errors(spec: str, match: str) -> None:
    with pytest.raises(MaterialError, match=match):
        material_from_spec(spec)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ('driver = "simulated"', 'driver = "webcam"', r"driver 'webcam' is unknown"),
        ("simulated = true", "simulated = false", r"simulated camera renders from the simulator"),
    ],
)
def test_camera_driver_checks(rig_sim_path: Path, tmp_path: Path, old: str, new: str,
                              match: str) -> None:
    from acquisition.devices.rig import check_camera_driver

    with pytest.raises(ConfigError, match=match):
        check_camera_driver(load_rig(edited(rig_sim_path, tmp_path, old, new)))


def test_camera_port_is_read(rig_sim_path: Path, tmp_path: Path) -> None:
    rig = load_rig(edited(rig_sim_path, tmp_path, 'driver = "simulated"',
                          'driver = "simulated"\nport = "usb:001,004"'))
    assert rig.camera.port == "usb:001,004"
    assert load_rig(rig_sim_path).camera.port is None


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("shadow_cone_deg = 8.0", "shadow_cone_deg = 0.14",
         r"\[geometry\] shadow_cone_deg: must be ≥ 0.5°, got 0.14° \(degrees; 0.14 rad would be "
         r"8.02°: write it in degrees\)"),
        ("shadow_cone_deg = 8.0", "shadow_cone_deg = 60", r"shadow_cone_deg: must be ≤ 45°"),
        ("max_elevation_deg = 85.0", "max_elevation_deg = 1.48",
         r"max_elevation_deg: must be ≥ 5°, got 1.48° \(degrees; 1.48 rad would be 84.8°"),
        ("light_distance_m = 0.5", "light_distance_m = 500",
         r"\[geometry\] light_distance_m: must be ≤ 5 m, got 500 m"),
        ("camera_distance_m = 0.6", "camera_distance_m = 0.006",
         r"camera_distance_m: must be ≥ 0.05 m, got 0.006 m"),
        ("settle_s = 0.05", "settle_s = 50", r"settle_s: must be ≤ 10 s"),
        ("settle_s = 0.05", "settle_s = nan", r"settle_s: must be a finite number, got nan"),
        ("exposure_s = 0.01", "exposure_s = 7200", r"\[camera\] exposure_s: must be ≤ 3600 s"),
        ("iso = 100", "iso = 1000000", r"\[camera\] iso: must be ≤ 102400"),
        ("baud = 57600", "baud = 12345", r"\[buses.main\] baud: 12345 is not a rate dynamixel_sdk"),
        ("time_scale = 25.0", "time_scale = 1e6", r"\[simulation\] time_scale: must be ≤ 10000"),
        ("intensity_w_per_sr = 10.0", "intensity_w_per_sr = 0",
         r"\[light\] intensity_w_per_sr: must be ≥ 1e-09 W/sr"),
        ("intensity_w_per_sr = 10.0", "intensity_w_per_sr = 1e9", r"must be ≤ 1e\+06 W/sr"),
        ("reflectance = 0.99", "reflectance = 99", r"\[white_reference\] reflectance"),
        ("min_deg = -179", "min_deg = -179\ntolerance_deg = 20",
         r"\[axes.camera_phi\] tolerance_deg: must be ≤ 10°"),
        ("profile_velocity = 150", "profile_velocity = 0",
         r"\[axes.camera_phi\] profile_velocity: must be ≥ 1"),
        ("full_well_e = 30000.0", "full_well_e = 3e9",
         r"\[camera.sensor\] full_well_e: must be ≤ 1e\+07"),
        ("gain_e_per_dn = 2.0", "gain_e_per_dn = -2.0",
         r"\[camera.sensor\]: sensor parameter 'gain_e_per_dn' = -2.0 must be a finite number > 0"),
        ("[white_reference]", "[arms]\nclearance_m = 5\n[white_reference]",
         r"\[arms\] clearance_m: must be ≤ 0.1 m, got 5 m"),
        ("[white_reference]", "[sample]\nsize_m = 50\n[white_reference]",
         r"\[sample\] size_m: must be ≤ 1 m, got 50 m"),
        ("[white_reference]", "[timing]\nbus_cycle_s = 30\n[white_reference]",
         r"\[timing\] bus_cycle_s: must be ≤ 1 s"),
    ],
)
def test_rig_plausible_ranges(rig_sim_path: Path, tmp_path: Path, old: str, new: str,
                              match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        load_rig(edited(rig_sim_path, tmp_path, old, new))
    assert "\n" not in str(info.value)
    assert str(tmp_path) in str(info.value)


def test_light_stage_camera_must_look_down(tmp_path: Path) -> None:
    src = Path(__file__).resolve().parent.parent / "examples" / "rig-lightstage-sim.toml"
    text = src.read_text()
    assert "camera_angles_deg = [30" in text
    path = tmp_path / "stage.toml"
    path.write_text(text.replace("camera_angles_deg = [30", "camera_angles_deg = [120", 1))
    with pytest.raises(ConfigError, match=r"\[light_stage\] camera_angles_deg: must be"):
        load_rig(path)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("step = 15 }", "step = 0.001 }", r"\[sampling.theta_i\] step: must be ≥ 0.01°"),
        ('kind = "grid"', 'kind = "grid"\nbin_deg = 0.01', r"\[sampling\] bin_deg: must be ≥ 0.1°"),
        ("[sampling]", "[constraints]\nshadow_cone_deg = 0.14\n[sampling]",
         r"\[constraints\] shadow_cone_deg: must be ≥ 0.5°, got 0.14° \(degrees; 0.14 rad would "
         r'be 8.02°: write it in degrees or set units = "rad" in the plan\)'),
        ("[sampling]", "[constraints]\nshadow_cone_deg = 60\n[sampling]",
         r"shadow_cone_deg: must be ≤ 45°"),
        ("[sampling]", "[capture]\nexposure_s = 1e5\n[sampling]",
         r"\[capture\] exposure_s: must be ≤ 3600 s"),
        ("[sampling]", "[capture]\niso = 0\n[sampling]", r"\[capture\] iso: must be ≥ 1"),
        ("[sampling]", "[capture]\ntarget_snr = 1e9\n[sampling]", r"target_snr: must be ≤ 10000"),
        ("[sampling]", 'units = "rad"\n[sampling]',
         r"\[sampling.theta_i\] stop: must be ≤ 90°, got 75 rad"),
    ],
)
def test_plan_plausible_ranges(plan_quick_path: Path, tmp_path: Path, old: str, new: str,
                               match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        load_plan(edited(plan_quick_path, tmp_path, old, new))
    assert "\n" not in str(info.value)


def test_plan_iso_must_suit_the_simulated_camera(plan_quick_path: Path, rig_sim_path: Path,
                                                 tmp_path: Path) -> None:
    from acquisition import api

    plan = edited(plan_quick_path, tmp_path, "[sampling]", "[capture]\niso = 200000\n[sampling]")
    with pytest.raises(ConfigError, match=r"\[capture\] iso: the simulated camera .* takes ISO "
                                          r"50–102400, got 200000"):
        api.capture(rig_sim_path, plan, tmp_path / "s")
    assert not (tmp_path / "s").exists()
