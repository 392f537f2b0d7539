"""The compiled evaluators of the analytic materials (simulators.material_kernels) against
their reference, each class's numpy ``eval_vectors``: the same BRDF to 1e-12 relative (and 0
exactly where the reference is 0) over random directions, both hemispheres."""

from __future__ import annotations

import zlib

import numpy as np
import pytest

from simulators.material_kernels import eval_packed_vectors, packed_material
from simulators.material_models import MicrofacetMaterial
from simulators.materials import GGX, Lambert, Material, material_from_spec

SPECS = [
    "lambert:albedo=0.5",
    "lambert:albedo=0.5/0.3/0.1",
    "ggx:albedo=0.2,alpha=0.3,f0=0.04",
    "ggx:albedo=0.2,alpha=0.02,f0=0.9",
    "ggx:albedo=0.2/0.1/0.05,alpha=0.3,f0=0.04,masking=height-correlated",
    "ggx:albedo=0.1,alpha=0.2,fresnel=dielectric,eta=1.5",
    "ggx:albedo=0,alpha=0.2,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2",
    "ggx:albedo=0.1,alpha=0.1,f0=0.04,alpha2=0.5,mix=0.3",
    "beckmann:albedo=0.1,alpha=0.1,f0=0.04",
    "beckmann:albedo=0.1,alpha=0.6,f0=0.02/0.04/0.08,masking=height-correlated",
    "phong:albedo=0.3,ks=0.2,e=50",
    "phong:albedo=0.3,ks=0.2/0.1/0.1,e=50,ks2=0.1,e2=3.5",
    "blinn-phong:albedo=0.3,ks=0.05,e=100",
    "oren-nayar:albedo=0.5,sigma_deg=20",
    "oren-nayar:albedo=0.9/0.5/0.2,sigma_deg=60",
]


def random_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("spec", SPECS)
def test_the_compiled_evaluator_is_the_numpy_formula(spec: str) -> None:
    material = material_from_spec(spec)
    packed = packed_material(material)
    assert packed is not None, spec
    rng = np.random.default_rng(zlib.crc32(spec.encode()))
    wi, wo = random_directions(rng, 20_000), random_directions(rng, 20_000)
    wo[:5000, 2] = np.abs(wo[:5000, 2])  # a quarter of pairs both up, a quarter more
    wi[:2500, 2] = np.abs(wi[:2500, 2])
    wo[-3:] = wi[-3:] = [0.0, 0.0, 1.0]  # normal incidence and view: h along the normal
    with np.errstate(divide="ignore", invalid="ignore"):
        reference = material.eval_vectors(wi, wo)
    compiled = eval_packed_vectors(*packed, wi, wo)
    assert (reference > 0).any(axis=1).mean() > 0.2  # the comparison is not all zeros
    np.testing.assert_allclose(compiled, reference, rtol=1e-12, atol=0.0)


def test_a_material_without_a_compiled_evaluator_packs_to_none() -> None:
    """Measured materials and subclasses (which may evaluate otherwise) are left to numpy."""

    class Brighter(Lambert):
        def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return 2.0 * super().eval_vectors(wi, wo)

    class Tabulated(Material):
        spec = "table:"

        def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
            return np.zeros(np.shape(wi))

    assert packed_material(Brighter(0.5)) is None
    assert packed_material(Tabulated()) is None
    assert packed_material(GGX(0.2, 0.3, 0.04)) is not None
    assert packed_material(MicrofacetMaterial((0.1, 0.1, 0.1), 0.2)) is not None
