"""Dask distributed reduction against a ``multiprocessing.Pool`` of the same size, on one
image-based session: 100 frames of 6 MP (the simulated sphere rig, ``examples/rig-sphere-sim
.toml``, at a 3000 × 2000 sensor, the sphere ~480 superpixels in radius), captured in a
temporary folder.

Three ways to reduce the same session, each twice, in the order serial, pool, Dask, Dask,
pool, serial (a shared machine's load drifts: a linear drift cancels; compare within a run),
each in a fresh process (``bench/_dask_child.py``) that has reduced one frame before the clock
starts (numba's kernels loaded):

* serial: :class:`ImageReducer` opened here, every frame into one partial, finished here;
* Pool: a 2-process ``multiprocessing.Pool`` (spawn: numba's GNU OpenMP thread pool is not
  fork-safe), each process warmed by one frame and given its share of the cores for numba's
  threads, as Dask's workers are, before the clock starts; then the session opened here, the
  odd and the even frames reduced into one partial each, merged and finished here — the best
  a pool does (two tasks, two partials shipped);
* Dask: :func:`acquisition.reduction.distributed.reduce_on_cluster` on a 2-worker
  ``LocalCluster`` configured as ``gonio reduce --workers 2`` configures it (one thread per
  worker, its share of the cores for numba's threads) — the session opened on a worker, one
  task per frame, partials merged on the workers, one merged partial finished here. The
  cluster is started, and each worker has reduced one frame in a task (numba's cache
  loaded), before the clock starts.

The three tables must be equal bit for bit (else the benchmark fails). (The file is not
called ``distributed.py``: run from ``bench/``, it would shadow the ``distributed`` package.)
Reported:

* ``dask_vs_pool_efficiency``: Dask's speed-up over serial ÷ the pool's (= the pool's wall
  time ÷ Dask's, summed over the two runs each; goal ≥ 0.8);
* ``dask_cpu_overhead``: the workers' CPU-seconds (``getrusage`` on every worker, before and
  after each run) ÷ the serial reductions' CPU-seconds (goal ≤ 1.10);
  ``dask_cpu_overhead_with_client`` adds this process's CPU during the Dask runs (the client,
  and the LocalCluster's scheduler, which runs in it); ``pool_cpu_overhead``: the same for
  the pool (children and this process), the yardstick of what two processes cost on this
  machine;
* the speed-ups, the serial time (mean of two), the core count (``dask_bench_cores``), the
  1-minute load average at the start, the capture's time, frames and megapixels.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RIG = ROOT / "examples" / "rig-sphere-sim.toml"
FRAMES = 100
WIDTH, HEIGHT = 3000, 2000
MATERIAL = "ggx:albedo=0.2,alpha=0.2,f0=0.2"
ORDER = ("serial", "pool", "dask", "dask", "pool", "serial")
"""Each way twice, symmetric in time: a linear drift of the machine's load cancels."""


def _rig(folder: Path) -> Path:
    """The sphere rig at WIDTH × HEIGHT px: the sphere's image scaled to stay inside the frame
    (radius ~480 of 1000 superpixels), the white plate's ROI at the image centre."""
    text = RIG.read_text()
    cx, cy = WIDTH // 4, HEIGHT // 4  # image centre, superpixels
    for old, new in (("width = 1000", f"width = {WIDTH}"), ("height = 1000", f"height = {HEIGHT}"),
                     ("fx = 7200.0", "fx = 14400.0"), ("fy = 7200.0", "fy = 14400.0"),
                     ("roi = [200, 200, 300, 300]", f"roi = [{cx - 50}, {cy - 50}, {cx + 50}, {cy + 50}]"),
                     ("time_scale = 25.0", "time_scale = 200.0")):
        if old not in text:
            raise RuntimeError(f"{RIG} changed: {old!r} not found")
        text = text.replace(old, new)
    path = folder / "rig.toml"
    path.write_text(text)
    return path


def _plan(folder: Path, rig: Path) -> Path:
    """bench/image_session.py's plan of FRAMES accepted poses."""
    spec = importlib.util.spec_from_file_location("bench_image_session_plan", HERE / "image_session.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module._plan(folder, rig, FRAMES)


def _run(how: str, session: Path) -> dict[str, float | str]:
    out = subprocess.run([sys.executable, str(HERE / "_dask_child.py"), how, str(session)],
                         capture_output=True,
                         text=True, check=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    return json.loads(out.stdout.strip().splitlines()[-1])


def _sum(runs: list[dict[str, float | str]], what: str) -> float:
    return sum(float(r[what]) for r in runs)


def bench_dask_reduction() -> dict[str, dict[str, float | str]]:
    from acquisition import api

    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rig = _rig(folder)
        session = folder / "session"
        t = time.perf_counter()
        api.capture(rig, _plan(folder, rig), session, material=MATERIAL, seed=1)
        capture_s = time.perf_counter() - t
        runs: dict[str, list[dict[str, float | str]]] = {"serial": [], "pool": [], "dask": []}
        for how in ORDER:
            runs[how].append(_run(how, session))
    every = [r for rs in runs.values() for r in rs]
    if len({r["digest"] for r in every}) != 1:
        raise RuntimeError("the serial, pool and Dask tables differ")
    if {r["frames"] for r in every} != {FRAMES}:
        raise RuntimeError(f"reduced {sorted({r['frames'] for r in every})} frames, expected {FRAMES}")
    serial_s, pool_s, dask_s = (_sum(runs[k], "wall_s") for k in ("serial", "pool", "dask"))
    serial_cpu, dask_cpu = _sum(runs["serial"], "cpu_s"), _sum(runs["dask"], "cpu_s")
    return {
        "dask_vs_pool_efficiency": {"value": pool_s / dask_s, "unit": "ratio"},
        "dask_speedup_2_workers": {"value": serial_s / dask_s, "unit": "ratio"},
        "pool_speedup_2_processes": {"value": serial_s / pool_s, "unit": "ratio"},
        "dask_cpu_overhead": {"value": dask_cpu / serial_cpu, "unit": "ratio"},
        "dask_cpu_overhead_with_client": {
            "value": (dask_cpu + _sum(runs["dask"], "client_cpu_s")) / serial_cpu, "unit": "ratio"},
        "pool_cpu_overhead": {"value": _sum(runs["pool"], "cpu_s") / serial_cpu, "unit": "ratio"},
        "dask_bench_serial_s": {"value": serial_s / len(runs["serial"]), "unit": "s"},
        "dask_bench_cores": {"value": os.cpu_count() or 0, "unit": "cores"},
        "dask_bench_load_avg_1min": {"value": load, "unit": "processes"},
        "dask_bench_capture_s": {"value": capture_s, "unit": "s"},
        "dask_bench_frames": {"value": FRAMES, "unit": "frames"},
        "dask_bench_megapixels": {"value": WIDTH * HEIGHT / 1e6, "unit": "MP"},
    }


if __name__ == "__main__":
    for key, fig in bench_dask_reduction().items():
        print(f"{key}: {fig['value']:.6g} {fig['unit']}")
