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
        ("phong:n=10", "unknown material"),
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
