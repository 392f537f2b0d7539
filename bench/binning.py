"""Binning throughput into the MERL 90 × 90 × 180 × RGB table.

``bench_binning()`` bins 10 M samples in image-like coherent order (pixels of a sphere lit by
a point light, row by row, frame by frame) on one core and reports

* ``binning_msamples_per_s``: the public path from (θh, θd, φd) in degrees
  (:meth:`MerlTable.add_halfdiff`, numba backend: bin indices with the reference reader's
  arithmetic, then count, Σ, Σ² per channel added exactly as fixed-point integers), compiled
  beforehand;
* ``binning_numpy_msamples_per_s``: the same calls with the numpy backend, same run;
  ``binning_numba_speedup`` is the ratio;
* ``binning_vectors_msamples_per_s`` / ``binning_vectors_numpy_msamples_per_s``: the full path
  from light/view vectors (:meth:`MerlTable.add_vectors`, what image-based reduction calls per
  frame), numba and numpy;
* ``binning_bincount_baseline_msamples_per_s``: the straightforward numpy baseline (index of
  the whole batch, then seven ``np.bincount`` calls);
* ``binning_jit_compile_s``: CPU time to compile the two benchmarked kernels from scratch
  (fresh process, empty numba cache), and ``binning_jit_cache_load_s``: the same first calls
  in a later process that loads them from that cache (imports of numpy and numba included);
  both are excluded from the rates.

Rates use the CPU time of the binning thread (``time.thread_time``), best of a few repeats:
the machines are shared, and CPU time is what "per core" means.

Where the time goes (one core): the exact sums cost most. Per sample the numba path classifies
and copies x, x², splits the six values into three parts at fixed binary points in a
vectorised pass, sums a run of one bin's samples part by part (exactly, in float64) and adds
the run to the store once (the flush and the bin → row map cost most where runs are short);
then come the bin index and, on the vector path, the portable inverse trigonometric functions.
Before the sums were exact (float64 added in sample order) the halfdiff path ran at ~90 M/s,
the vector path at ~18 M/s; numpy's integer scatter-adds top out near 8 M/s.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from acquisition.geometry.halfdiff import MERL_BINS, halfdiff_rad_from_vectors, merl_flat_index_rad
from acquisition.tables import MerlTable

N_SAMPLES = 10_000_000


def _sphere_frame(light_theta_deg: float, res: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Light/view vectors (local frame, normal +z) for every lit, visible pixel of a unit
    sphere seen from +z at distance 10 with a point light at distance 6, in raster order."""
    u = (np.arange(res) + 0.5) / res * 2.0 - 1.0
    x, y = np.meshgrid(u, -u)
    on = x * x + y * y < 1.0
    x, y = x[on], y[on]
    n = np.stack([x, y, np.sqrt(1.0 - x * x - y * y)], axis=-1)
    t = np.radians(light_theta_deg)
    light = 6.0 * np.array([np.sin(t), 0.0, np.cos(t)])
    camera = np.array([0.0, 0.0, 10.0])
    l_dir = light - n
    l_dir /= np.linalg.norm(l_dir, axis=-1, keepdims=True)
    v_dir = camera - n
    v_dir /= np.linalg.norm(v_dir, axis=-1, keepdims=True)
    tangent = np.cross([0.0, 1.0, 0.0], n)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    bitangent = np.cross(n, tangent)
    frame = np.stack([tangent, bitangent, n], axis=-2)  # rows: local axes
    wi = np.einsum("nij,nj->ni", frame, l_dir)
    wo = np.einsum("nij,nj->ni", frame, v_dir)
    ok = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    return np.ascontiguousarray(wi[ok]), np.ascontiguousarray(wo[ok])


def _frames() -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(0)
    frames = []
    for light_deg in (15.0, 35.0, 55.0, 75.0):
        wi, wo = _sphere_frame(light_deg)
        th, td, pd = (np.degrees(a) for a in halfdiff_rad_from_vectors(wi, wo))
        rgb = rng.uniform(0.0, 1.0, (wi.shape[0], 3))
        frames.append({"wi": wi, "wo": wo, "th": th, "td": td, "pd": pd, "rgb": rgb})
    return frames


def _schedule(frames: list[dict[str, np.ndarray]]) -> list[tuple[dict[str, np.ndarray], int]]:
    """Frames (cycled) and how many of their samples to use, adding up to N_SAMPLES."""
    plan, total, k = [], 0, 0
    while total < N_SAMPLES:
        f = frames[k % len(frames)]
        n = min(f["th"].size, N_SAMPLES - total)
        plan.append((f, n))
        total += n
        k += 1
    return plan


def _rate(run, repeats: int = 3) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.thread_time()
        run()
        best = min(best, time.thread_time() - t0)
    return N_SAMPLES / best / 1e6


_COMPILE_SCRIPT = """
import time
t0 = time.process_time()
import numpy as np
from acquisition.tables import MerlTable
rgb = np.ones((4, 3))
table = MerlTable(backend="numba")
table.add_halfdiff(np.full(4, 10.0), 10.0, 10.0, rgb)
table.add_vectors(np.tile([0.0, 0.0, 1.0], (4, 1)), [0.0, 0.0, 1.0], rgb)
print(time.process_time() - t0)
"""


def _jit_times() -> tuple[float, float]:
    """CPU s to make the benchmarked kernels (``add_halfdiff``, ``add_vectors``) callable in a
    fresh process: (compiling them into an empty numba cache, loading them from that cache).

    Both include importing numpy, the tables and numba; each is a single measurement.
    """
    root = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        times = [
            float(
                subprocess.run(
                    [sys.executable, "-c", _COMPILE_SCRIPT], cwd=root, env=env, check=True,
                    capture_output=True, text=True,
                ).stdout.split()[-1]
            )
            for _ in range(2)
        ]
    return times[0], times[1]


def _bincount_baseline(th_deg: np.ndarray, td_deg: np.ndarray, pd_deg: np.ndarray,
                       rgb: np.ndarray) -> None:
    flat = merl_flat_index_rad(
        np.radians(th_deg), np.radians(td_deg), np.radians(pd_deg), clamp=False
    )
    np.bincount(flat, minlength=MERL_BINS)
    for c in range(3):
        v = rgb[:, c]
        np.bincount(flat, weights=v, minlength=MERL_BINS)
        np.bincount(flat, weights=v * v, minlength=MERL_BINS)


def bench_binning() -> dict[str, dict[str, float | str]]:
    plan = _schedule(_frames())

    def halfdiff_path(backend: str) -> None:
        table = MerlTable(backend=backend)
        for f, n in plan:
            table.add_halfdiff(f["th"][:n], f["td"][:n], f["pd"][:n], f["rgb"][:n])
        assert table.n_samples == N_SAMPLES

    def vectors_path(backend: str) -> None:
        table = MerlTable(backend=backend)
        for f, n in plan:
            table.add_vectors(f["wi"][:n], f["wo"][:n], f["rgb"][:n])
        assert table.n_samples == N_SAMPLES

    def baseline() -> None:
        for f, n in plan:
            _bincount_baseline(f["th"][:n], f["td"][:n], f["pd"][:n], f["rgb"][:n])

    compile_s, cache_load_s = _jit_times()
    warm = MerlTable(backend="numba")  # load the compiled kernels before timing
    f = plan[0][0]
    warm.add_halfdiff(f["th"][:10], f["td"][:10], f["pd"][:10], f["rgb"][:10])
    warm.add_vectors(f["wi"][:10], f["wo"][:10], f["rgb"][:10])

    numba_rate = _rate(lambda: halfdiff_path("numba"), repeats=5)
    numpy_rate = _rate(lambda: halfdiff_path("numpy"))
    mps = "Msamples/s"
    return {
        "binning_msamples_per_s": {"value": numba_rate, "unit": mps},
        "binning_numpy_msamples_per_s": {"value": numpy_rate, "unit": mps},
        "binning_numba_speedup": {"value": numba_rate / numpy_rate, "unit": "x"},
        "binning_vectors_msamples_per_s": {
            "value": _rate(lambda: vectors_path("numba")), "unit": mps
        },
        "binning_vectors_numpy_msamples_per_s": {
            "value": _rate(lambda: vectors_path("numpy"), repeats=2), "unit": mps
        },
        "binning_bincount_baseline_msamples_per_s": {"value": _rate(baseline, 2), "unit": mps},
        "binning_jit_compile_s": {"value": compile_s, "unit": "s"},
        "binning_jit_cache_load_s": {"value": cache_load_s, "unit": "s"},
    }


if __name__ == "__main__":
    for key, fig in bench_binning().items():
        print(f"{key}: {fig['value']:.3g} {fig['unit']}")
