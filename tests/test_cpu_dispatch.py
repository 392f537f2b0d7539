"""Tables are the same bits whatever the CPU: the reduction under reduced SIMD features.

numpy picks its loops at run time by the CPU's SIMD features (``NPY_DISABLE_CPU_FEATURES``
turns some off) and OpenBLAS its kernels by the CPU's core (``OPENBLAS_CORETYPE``). A
worker on another machine is this machine with other features: the same session reduced in
subprocesses under each must give every dataset of the table file bit for bit (issue 15: the
same table whatever the machines). Before the reduction's per-sample arithmetic was made
independent of them, numpy's AVX-512 ``arctan2`` moved the image-based table's mean angles and
OpenBLAS's fused ``dgemv`` its white-reference uncertainty.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, TINY_PLAN_ARGS, grid_plan_text
from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
from test_streaming import SPHERE_MATERIAL, table_arrays

from acquisition import api
from acquisition.geometry.kinematics import poses_from_directions
from acquisition.reduction.fixedorder import dot3, weighted_variance
from acquisition.reduction.pose_kernels import RAD_TO_DEG, sample_poses
from acquisition.tables import portable_trig

ROOT = Path(__file__).resolve().parent.parent
SPHERE_PLAN = """format_version = 1
name = "sphere-cpu"
[sampling]
kind = "list"
reciprocal = "both"
bin_deg = 5
poses = [[15, 45, 180], [45, 45, 180], [30, 45, 0]]
[capture]
reference_every = 2
"""
NO_AVX512 = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
             "OPENBLAS_CORETYPE": "Haswell"}
BASELINE = {"NPY_DISABLE_CPU_FEATURES": " ".join(__cpu_dispatch__),
            "OPENBLAS_CORETYPE": "Sandybridge"}
"""numpy's baseline loops only (x86-64-v2: no AVX2, no FMA) and OpenBLAS without FMA."""

# Reduce in a fresh process; print the table's arrays' digests and numpy's and the kernel's
# angles of fixed directions (to show the features really changed numpy's arithmetic).
_REDUCE = """
import hashlib, json, sys
import numpy as np
from acquisition import api
from acquisition.reduction.pose_kernels import sample_poses
api.reduce(sys.argv[1], sys.argv[2])
v = np.random.default_rng(5).normal(size=(4096, 3))
def digest(a): return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()
print(json.dumps({"arctan2": digest(np.arctan2(v[:, 1], v[:, 0])),
                  "kernel": digest(sample_poses(v, v[::-1]))}))
"""


def _reduce(session: Path, out: Path, env: dict[str, str]) -> dict[str, str]:
    done = subprocess.run([sys.executable, "-c", _REDUCE, str(session), str(out)], cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **env},
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.splitlines()[-1])


def _assert_same(a: Path, b: Path) -> None:
    ta, tb = table_arrays(a), table_arrays(b)
    assert ta.keys() == tb.keys() and len(ta) >= 10
    differ = [k for k in ta if not np.array_equal(ta[k], tb[k], equal_nan=True)]
    assert not differ, f"datasets that depend on the CPU's features: {differ}"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cpu")
    (root / "sphere.toml").write_text(SPHERE_PLAN)
    (root / "point.toml").write_text(grid_plan_text(*TINY_PLAN_ARGS, name="tiny"))
    api.capture(EXAMPLES / "rig-sphere-sim.toml", root / "sphere.toml", root / "sphere",
                material=SPHERE_MATERIAL, seed=3)
    api.capture(EXAMPLES / "rig-sim.toml", root / "point.toml", root / "point", seed=3)
    return {"sphere": root / "sphere", "point": root / "point"}


def test_image_based_table_is_the_same_under_other_cpu_features(sessions, tmp_path):
    ref = _reduce(sessions["sphere"], tmp_path / "ref.h5", {})
    no512 = _reduce(sessions["sphere"], tmp_path / "no512.h5", NO_AVX512)
    # The numpy backend (einsum-free geometry, libm bins) on numpy's baseline loops.
    base = _reduce(sessions["sphere"], tmp_path / "base.h5",
                   {**BASELINE, "GONIO_BINNING_BACKEND": "numpy"})
    _assert_same(tmp_path / "ref.h5", tmp_path / "no512.h5")
    _assert_same(tmp_path / "ref.h5", tmp_path / "base.h5")
    assert ref["kernel"] == no512["kernel"] == base["kernel"]
    # The features did change numpy's own arctan2 (on a CPU with AVX-512).
    if __cpu_features__.get("X86_V4") and "X86_V4" in __cpu_dispatch__:
        assert ref["arctan2"] != no512["arctan2"]


def test_point_table_is_the_same_under_other_cpu_features(sessions, tmp_path):
    _reduce(sessions["point"], tmp_path / "ref.h5", {})
    _reduce(sessions["point"], tmp_path / "base.h5", BASELINE)
    _assert_same(tmp_path / "ref.h5", tmp_path / "base.h5")


def _python_atan2(y: float, x: float) -> float:
    """portable_trig.atan2's arithmetic in plain Python floats (IEEE doubles)."""
    if math.isnan(x) or math.isnan(y):
        return math.nan
    ax, ay = abs(x), abs(y)
    swap = ay > ax
    num, den = (ax, ay) if swap else (ay, ax)
    t = num / den if den > 0.0 else 0.0
    big = t > portable_trig.TAN_PI_8
    u = (t - 1.0) / (t + 1.0) if big else t
    z = u * u
    p = _P[-1]
    for c in reversed(_P[:-1]):
        p = p * z + c
    r = u + u * (z * p)
    r = math.pi / 4.0 + r if big else r
    r = math.pi / 2.0 - r if swap else r
    r = math.pi - r if math.copysign(1.0, x) < 0.0 else r
    return math.copysign(r, y)


_P = [getattr(portable_trig, f"P{k}") for k in range(11)]


def _python_poses(light: np.ndarray, camera: np.ndarray, atan2=_python_atan2) -> np.ndarray:
    """(θi, θr, Δφ) degrees with ``atan2`` in Python, one sample at a time."""
    def theta(x: float, y: float, z: float) -> float:
        return atan2(math.sqrt(x * x + y * y), z) * RAD_TO_DEG

    def wrap(a: float) -> float:
        w = (a + 180.0) % 360.0 - 180.0
        return 180.0 if w == -180.0 else w

    return np.array([(theta(*li), theta(*ca), wrap(atan2(ca[1], ca[0]) * RAD_TO_DEG
                                                   - atan2(li[1], li[0]) * RAD_TO_DEG))
                     for li, ca in zip(light.tolist(), camera.tolist(), strict=True)])


def test_sample_poses_are_portable_arithmetic_bit_for_bit_and_libm_within_ulps():
    """The kernel (vectorised) is the portable atan2's arithmetic done one sample at a time
    in Python, bit for bit; libm's atan2 and numpy's angles agree to a few ulp."""
    rng = np.random.default_rng(11)
    light, camera = rng.normal(size=(2, 5000, 3))
    light /= np.sqrt(dot3(light, light))[:, None]
    camera /= np.sqrt(dot3(camera, camera))[:, None]
    edge = [([0, 0, 1], [1, 0, 0]), ([0, 0, -1], [0, 0, 1]), ([-1, 0, 0], [1, 0, 0]),
            ([-1, -0.0, 0], [-1, 0.0, 0]), ([0, -0.0, 1], [0, 0, 1]), ([np.nan, 0, 1], [0, 0, 1])]
    light[:len(edge)] = [e[0] for e in edge]
    camera[:len(edge)] = [e[1] for e in edge]
    got = sample_poses(light, camera)
    assert np.array_equal(got, _python_poses(light, camera), equal_nan=True)
    assert np.allclose(got, _python_poses(light, camera, math.atan2), rtol=1e-15, atol=1e-13,
                       equal_nan=True)
    assert np.allclose(got, poses_from_directions(light, camera), rtol=0, atol=1e-10,
                       equal_nan=True)
    assert got[2, 2] == 180.0 and got[3, 2] == 0.0  # Δφ in (−180, 180]; −0 azimuth is −180°
    with pytest.raises(ValueError, match="camera directions"):
        sample_poses(light, camera[:3])


def test_wrap_without_fmod_is_floor_modulo_over_its_range():
    """pose_kernels._wrap_deg (one exact ± 360) equals (a + 180) % 360 − 180 on [−540, 540)."""
    from numba import njit

    from acquisition.reduction.pose_kernels import _wrap_deg

    @njit(fastmath=False, error_model="numpy")
    def wrap_all(a, out):  # pragma: no cover - compiled
        for i in range(a.size):
            out[i] = _wrap_deg(a[i])

    rng = np.random.default_rng(12)
    a = np.concatenate([rng.uniform(-540, 540, 100_000), np.arange(-540.0, 540.0, 0.5),
                        np.nextafter(np.arange(-540.0, 541.0, 180.0), 0.0), [-0.0, math.nan]])
    out = np.empty(a.size)
    wrap_all(a, out)
    want = (a + 180.0) % 360.0 - 180.0
    want[want == -180.0] = 180.0
    assert np.array_equal(out, want, equal_nan=True)
    assert np.array_equal(np.signbit(out), np.signbit(want))


def test_weighted_variance_rounds_each_product_then_adds_in_order():
    w = np.array([0.3, 0.7, 0.0])
    v = np.array([[1e-3, 2.0, 3.5], [7e-4, 0.1, 1e9], [5.0, 5.0, 5.0]])
    want = [(w[0] ** 2 * v[0, c] + w[1] ** 2 * v[1, c]) + w[2] ** 2 * v[2, c] for c in range(3)]
    assert weighted_variance(w, v).tolist() == want
