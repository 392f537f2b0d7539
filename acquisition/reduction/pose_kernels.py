"""(θi, θr, Δφ) of per-pixel samples, the same bits on every CPU and every C library.

numpy's ``arctan2`` dispatches at run time on the CPU's SIMD features: with AVX-512 (numpy 2's
``X86_V4`` target) it runs a vector routine whose last bit differs from libm's for ~7 % of
arguments, so :func:`acquisition.geometry.kinematics.poses_from_directions` gives a table's
mean angles that depend on the machine (tests/test_cpu_dispatch.py shows it by disabling
features with ``NPY_DISABLE_CPU_FEATURES``); and libm's own ``atan2`` is the C library's
(glibc, musl, macOS differ in the last bit). Here every sample goes through

    θ = atan2(√(x·x + y·y), z) · (180/π),   φ = atan2(y, x) · (180/π),
    Δφ = φc − φl wrapped into (−180, 180]

with :func:`acquisition.tables.portable_trig.atan2` (+ − × / √ only, within 3 ulp; no fast-math,
no contraction), so the bits depend on nothing but IEEE arithmetic, and a loop over samples
vectorises (about 15× libm's scalar calls). It agrees with
:func:`~acquisition.geometry.kinematics.poses_from_directions` to a few ulp;
tests/test_cpu_dispatch.py compares it bit for bit with the same arithmetic in plain Python.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels

from drivers.numba_cache import drop_stale_cache  # noqa: E402

_TABLES = Path(__file__).resolve().parents[1] / "tables"
drop_stale_cache(__file__, (_TABLES / "portable_trig.py", _TABLES / "kernels.py"))

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.tables.kernels import PAIR_BLOCK, pair_columns  # noqa: E402
from acquisition.tables.portable_trig import atan2  # noqa: E402

RAD_TO_DEG = 180.0 / np.pi
"""Radians to degrees: one multiplication (np.degrees's constant)."""

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


@njit(inline="always", **_JIT)
def _wrap_deg(angle):  # pragma: no cover - compiled
    """``wrap_deg_array`` of one angle in [−540°, 540°): (a + 180) mod 360 − 180 (floor
    modulo), −180 → 180. The modulo is one exact ± 360 here (what ``fmod`` then + 360 gives
    in this range: a ± 360 is exact by Sterbenz's lemma or rounds as that + 360 does), so the
    loop stays free of libm's ``fmod`` and vectorises; a pose's Δφ lies within ±360.1°."""
    a = angle + 180.0
    a = a + 360.0 if a < 0.0 else (a - 360.0 if a >= 360.0 else a)
    w = a - 180.0
    return 180.0 if w == -180.0 else w


@njit(inline="always", **_JIT)
def pose(lx, ly, lz, cx, cy, cz):  # pragma: no cover - compiled
    """(θi, θr, Δφ) in degrees of one light/camera pair (module docstring)."""
    ti = atan2(np.sqrt(lx * lx + ly * ly), lz) * RAD_TO_DEG
    tr = atan2(np.sqrt(cx * cx + cy * cy), cz) * RAD_TO_DEG
    return ti, tr, _wrap_deg(atan2(cy, cx) * RAD_TO_DEG - atan2(ly, lx) * RAD_TO_DEG)


@njit(**_JIT)
def _contiguous_poses(c, m, ti, tr, dp):  # pragma: no cover - compiled
    """Poses of the m pairs in the columns of c (6, ≥ m): a loop LLVM vectorises."""
    for j in range(m):
        ti[j], tr[j], dp[j] = pose(c[0, j], c[1, j], c[2, j], c[3, j], c[4, j], c[5, j])


@njit(**_JIT)
def block_poses(light, camera, a, m, scratch, ti, tr, dp):  # pragma: no cover - compiled
    """Poses (deg) of samples a … a + m − 1 of light/camera (N, 3) into ti[:m], tr[:m],
    dp[:m], through ``scratch`` (6, ≥ m) (:func:`~acquisition.tables.kernels.pair_columns`)."""
    pair_columns(light, camera, a, m, scratch)
    _contiguous_poses(scratch, m, ti, tr, dp)


@njit(**_JIT)
def _poses(light, camera, out):  # pragma: no cover - compiled
    """Poses of every pair into out (3, N)."""
    scratch = np.empty((6, PAIR_BLOCK))
    for a in range(0, light.shape[0], PAIR_BLOCK):
        m = min(PAIR_BLOCK, light.shape[0] - a)
        block_poses(light, camera, a, m, scratch, out[0, a:], out[1, a:], out[2, a:])


def sample_poses(light: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(θi, θr, Δφ) in degrees, shape (N, 3), of unit light/camera vectors (N, 3) in the
    sample frame; the same bits on every CPU (module docstring)."""
    light = np.ascontiguousarray(light, dtype=np.float64).reshape(-1, 3)
    camera = np.ascontiguousarray(camera, dtype=np.float64).reshape(-1, 3)
    if light.shape != camera.shape:
        raise ValueError(f"{light.shape[0]} light but {camera.shape[0]} camera directions")
    out = np.empty((3, light.shape[0]))
    _poses(light, camera, out)
    return np.ascontiguousarray(out.T)

