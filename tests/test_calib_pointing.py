"""An image-based rig's camera pointing: the simulated camera renders through its true pointing
error, the calibration finds it from the sphere's place in the image, and the per-pixel
geometry with that pointing puts the sphere where the camera sees it."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES

from acquisition.calibrate.pointing import measure_pointing
from acquisition.calibrate.scans import Scope
from acquisition.config.rig import load_rig
from acquisition.devices.rig import open_devices
from acquisition.planning.planner import Planner
from acquisition.reduction.imaging import frame_geometry
from acquisition.simworld.scene import white_material

POINTING = (0.3, -0.2)


@pytest.fixture(scope="module")
def small_sphere_rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """rig-sphere-sim.toml at a fifth of its resolution (the sphere half the image wide), its
    camera turned by POINTING."""
    text = (EXAMPLES / "rig-sphere-sim.toml").read_text()
    for old, new in (("width = 1000", "width = 200"), ("height = 1000", "height = 200"),
                     ("fx = 7200.0", "fx = 720.0"), ("fy = 7200.0", "fy = 720.0"),
                     ("roi = [200, 200, 300, 300]", "roi = [40, 40, 60, 60]"),
                     ("[buses.main]", "[simulation.errors]\ncamera_pointing_deg = "
                                      f"[{POINTING[0]}, {POINTING[1]}]\n\n[buses.main]")):
        assert old in text
        text = text.replace(old, new, 1)
    path = tmp_path_factory.mktemp("pointing") / "rig.toml"
    path.write_text(text)
    return path


def test_the_sphere_in_the_image_gives_the_camera_pointing(small_sphere_rig: Path) -> None:
    rig = load_rig(small_sphere_rig)
    planner = Planner(rig)
    with open_devices(rig, planner, material=white_material(rig), seed=1) as dev, \
            tempfile.TemporaryDirectory() as tmp:
        found = measure_pointing(Scope(dev, rig, Path(tmp), rig.camera.exposure_s), rig, planner)
    print(f"pointing x {found.x_deg:+.4f}° ± {found.sigma_x_deg:.4f}°, "
          f"y {found.y_deg:+.4f}° ± {found.sigma_y_deg:.4f}°")
    assert found.x_deg == pytest.approx(POINTING[0], abs=0.02)
    assert found.y_deg == pytest.approx(POINTING[1], abs=0.02)
    assert found.radius_px == pytest.approx(720 * 0.02 / 0.6, rel=0.03)
    assert found.camera_distance_m == pytest.approx(rig.camera_distance_m, rel=0.03)


def test_the_pointed_camera_sees_the_sphere_off_centre(small_sphere_rig: Path) -> None:
    rig = load_rig(small_sphere_rig)
    light, camera = np.array([0.5, 0.0, 0.866]), np.array([-0.5, 0.0, 0.866])
    straight = frame_geometry(rig, light, camera, (100, 100))
    turned = frame_geometry(rig, light, camera, (100, 100), pointing_deg=POINTING)
    ys, xs = np.nonzero(straight.mask)
    yt, xt = np.nonzero(turned.mask)
    shift = 720 * np.tan(np.radians(POINTING))
    assert xt.mean() - xs.mean() == pytest.approx(-shift[0], abs=0.5)
    assert yt.mean() - ys.mean() == pytest.approx(-shift[1], abs=0.5)
