"""The simulated camera's compiled renderer (acquisition.simworld.render_kernel) against its
reference, the numpy path (optics.surface_view + scene.render_view): the same pixels on the
sample and the same radiance to 1e-9 relative, on a sphere, a flat sample and the white plate,
with a lamp of several points, a pointing error and a raised sample; the same bits on one
thread and on many; materials without a compiled evaluator rendered by the numpy path."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from acquisition.config.rig import RigConfig, load_rig
from acquisition.simworld import render_kernel
from acquisition.simworld.misalignment import disc_offsets
from acquisition.simworld.scene import render_image, render_image_numpy
from simulators.materials import Lambert, material_from_spec

SPHERE_RIG = Path(__file__).resolve().parent.parent / "examples" / "rig-sphere-sim.toml"
SHAPE = (120, 160)
MATERIALS = [
    "lambert:albedo=0.5/0.3/0.1",
    "ggx:albedo=0.2,alpha=0.2,f0=0.2",
    "ggx:albedo=0,alpha=0.2,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2",
    "beckmann:albedo=0.1,alpha=0.1,f0=0.04,alpha2=0.5,mix=0.3",
    "blinn-phong:albedo=0.3,ks=0.05,e=100",
    "oren-nayar:albedo=0.5,sigma_deg=20",
]


def unit(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def rig_with(sample: str) -> RigConfig:
    """The sphere rig, with a 2 cm sphere filling the small frame, or a flat 5 cm sample lit
    from 15 cm (cos θi / r² varies over it)."""
    rig = load_rig(SPHERE_RIG)
    fx = 7200.0 * SHAPE[0] / 500.0
    rig = dataclasses.replace(rig, camera=dataclasses.replace(
        rig.camera, intrinsics=dataclasses.replace(rig.camera.intrinsics, fx=fx, fy=fx)))
    if sample == "sphere":
        return rig
    return dataclasses.replace(rig, light_distance_m=0.15,
                               sample=dataclasses.replace(rig.sample, shape="flat"))


def lamp(rig: RigConfig, light: np.ndarray) -> np.ndarray:
    """7 points of a 1 cm disc about the light's direction at its distance (m)."""
    u = np.cross(light, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    d = disc_offsets(0.01, 7)
    return light * rig.light_distance_m + d[:, :1] * u + d[:, 1:] * np.cross(light, u)


def assert_same_render(compiled: np.ndarray, reference: np.ndarray) -> None:
    """Same pixels on the sample; radiance within 1e-9 relative, or within 1e-12 of the
    brightest pixel where a pixel is ill-conditioned (cos θi → 0 at the terminator, where
    either path's rounding is amplified)."""
    assert compiled.shape == reference.shape
    np.testing.assert_array_equal(compiled > 0, reference > 0)
    assert (reference > 0).any(axis=-1).mean() > 0.1  # not a comparison of black frames
    np.testing.assert_allclose(compiled, reference, rtol=1e-9, atol=1e-12 * reference.max())


CASES = [  # (sample, target, light θ, φ, camera θ, φ, pointing x, y, height m)
    ("sphere", None, 30.0, 180.0, 45.0, 0.0, 0.0, 0.0, 0.0),
    ("sphere", None, 60.0, 40.0, 20.0, 200.0, 0.3, -0.2, 0.002),
    ("sphere", None, 75.0, -120.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # camera at the zenith
    ("sphere", "flat", 10.0, 30.0, 45.0, 0.0, 0.1, 0.0, 0.001),  # the white plate
    ("flat", None, 50.0, 10.0, 70.0, 123.0, 1.0, 2.0, 0.0),
    ("flat", None, 35.0, 120.0, 10.0, -60.0, -0.5, 0.0, -0.003),
]


@pytest.mark.parametrize("material_spec", MATERIALS)
@pytest.mark.parametrize(("sample", "target", "lt", "lp", "ct", "cp", "px", "py", "h"), CASES)
def test_the_compiled_renderer_matches_the_numpy_renderer(
        sample: str, target: str | None, lt: float, lp: float, ct: float, cp: float,
        px: float, py: float, h: float, material_spec: str) -> None:
    rig = rig_with(sample)
    material = material_from_spec(material_spec)
    light, camera = unit(lt, lp), unit(ct, cp)
    points = lamp(rig, light)
    kw = {"pointing_deg": (px, py), "sample_height_m": h}
    compiled = render_image(rig, light, camera, material, SHAPE, target, light_points=points, **kw)
    reference = render_image_numpy(rig, camera, material, SHAPE, target, points, **kw)
    assert_same_render(compiled, reference)


def test_the_frame_is_the_same_on_one_thread_and_on_many(monkeypatch: pytest.MonkeyPatch) -> None:
    rig = rig_with("sphere")
    args = (rig, unit(40.0, 0.0), unit(30.0, 150.0), material_from_spec(MATERIALS[1]), SHAPE)
    monkeypatch.setattr(render_kernel, "PARALLEL_MIN_SUPERPIXELS", 10**12)
    serial = render_image(*args)
    monkeypatch.setattr(render_kernel, "PARALLEL_MIN_SUPERPIXELS", 0)
    np.testing.assert_array_equal(render_image(*args), serial)
    assert serial.max() > 0


def test_a_material_without_a_compiled_evaluator_is_rendered_by_numpy(
        monkeypatch: pytest.MonkeyPatch) -> None:
    class Brighter(Lambert):
        def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return 2.0 * super().eval_vectors(wi, wo)

    def compiled(*_: object, **__: object) -> None:
        raise AssertionError("a material without a compiled evaluator reached the kernel")

    rig = rig_with("sphere")
    light, camera = unit(20.0, 0.0), unit(35.0, 90.0)
    lambert = render_image(rig, light, camera, Lambert(0.4), SHAPE)
    monkeypatch.setattr(render_kernel, "render_frame", compiled)
    brighter = render_image(rig, light, camera, Brighter(0.4), SHAPE)
    assert_same_render(brighter, 2.0 * lambert)
