"""(θi, θr, Δφ) of per-pixel samples, the same bits on every CPU: a compiled pass calling libm.

numpy's ``arctan2`` dispatches at run time on the CPU's SIMD features: with AVX-512 (numpy 2's
``X86_V4`` target) it runs a vector routine whose last bit differs from libm's for ~7 % of
arguments, so :func:`acquisition.geometry.kinematics.poses_from_directions` gives a table's
mean angles that depend on the machine (tests/test_cpu_dispatch.py shows it by disabling
features with ``NPY_DISABLE_CPU_FEATURES``). Here every sample goes through

    θ = atan2(√(x·x + y·y), z) · (180/π),   φ = atan2(y, x) · (180/π),
    Δφ = φc − φl wrapped into (−180, 180]

with libm's ``atan2`` (scalar calls: no SVML, no fast-math, no contraction, as
:mod:`acquisition.tables.kernels`) and IEEE-exact ``+ − × /`` and √ otherwise. It agrees with
:func:`~acquisition.geometry.kinematics.poses_from_directions` to a few ulp (which uses
``hypot`` and numpy's own atan2); tests/test_cpu_dispatch.py compares it bit for bit with the
same arithmetic in Python's :mod:`math`.
"""

from __future__ import annotations

import math
import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

RAD_TO_DEG = 180.0 / math.pi
"""Radians to degrees: one multiplication (np.degrees's constant)."""

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


@njit(inline="always", **_JIT)
def _wrap_deg(angle):  # pragma: no cover - compiled
    """``wrap_deg_array`` of one angle: (a + 180) mod 360 − 180 (floor modulo), −180 → 180."""
    w = (angle + 180.0) % 360.0 - 180.0  # floor modulo, exact (as Python's and numpy's)
    return 180.0 if w == -180.0 else w


@njit(inline="always", **_JIT)
def pose(lx, ly, lz, cx, cy, cz):  # pragma: no cover - compiled
    """(θi, θr, Δφ) in degrees of one light/camera pair (module docstring)."""
    ti = math.atan2(math.sqrt(lx * lx + ly * ly), lz) * RAD_TO_DEG
    tr = math.atan2(math.sqrt(cx * cx + cy * cy), cz) * RAD_TO_DEG
    return ti, tr, _wrap_deg(math.atan2(cy, cx) * RAD_TO_DEG - math.atan2(ly, lx) * RAD_TO_DEG)


@njit(**_JIT)
def _poses(light, camera, out):  # pragma: no cover - compiled
    for k in range(light.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = pose(light[k, 0], light[k, 1], light[k, 2],
                                               camera[k, 0], camera[k, 1], camera[k, 2])


def sample_poses(light: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(θi, θr, Δφ) in degrees, shape (N, 3), of unit light/camera vectors (N, 3) in the
    sample frame; the same bits on every CPU (module docstring)."""
    light = np.ascontiguousarray(light, dtype=np.float64).reshape(-1, 3)
    camera = np.ascontiguousarray(camera, dtype=np.float64).reshape(-1, 3)
    if light.shape != camera.shape:
        raise ValueError(f"{light.shape[0]} light but {camera.shape[0]} camera directions")
    out = np.empty((light.shape[0], 3))
    _poses(light, camera, out)
    return out

