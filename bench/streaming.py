"""Streaming reduction's cost to a capture: ``gonio capture`` of plan-quick on the simulated
rig with its streaming worker (the table at the end) against ``--no-reduce``, whole processes,
interleaved A B B A so that a change in the machine's load falls on both.

``streaming_overhead`` is the median over rounds of (wall time with streaming) / (wall time
without); the rig time of every run is checked to be the same (the worker never delays a
move). The issue's goal is ≤ 1.25.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GONIO = Path(sys.executable).with_name("gonio")
ROUNDS = 4


def _capture(out: Path, stream: bool) -> tuple[float, float]:
    """Host wall seconds and rig seconds of one quick capture."""
    cmd = [str(GONIO), "capture", "--rig", str(ROOT / "examples/rig-sim.toml"), "--plan",
           str(ROOT / "examples/plan-quick.toml"), "--out", str(out), "--material",
           "lambert:albedo=0.5", "--json"]
    if not stream:
        cmd.append("--no-reduce")
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    report = json.loads(done.stdout)
    if stream != ("streamed" in report) or (stream and not report["streamed"].get("table")):
        raise RuntimeError(f"unexpected capture report: {done.stdout}")
    return wall, float(report["device_seconds"])


def bench_streaming() -> dict[str, dict[str, float | str]]:
    ratios, walls, rig_s = [], {True: [], False: []}, set()
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(ROUNDS):
            run = {}
            for i, stream in enumerate((False, True, True, False)):
                wall, rig = _capture(Path(tmp) / f"r{k}-{i}", stream)
                run.setdefault(stream, []).append(wall)
                walls[stream].append(wall)
                rig_s.add(round(rig, 9))
            ratios.append(sum(run[True]) / sum(run[False]))
    if len(rig_s) != 1:
        raise RuntimeError(f"the rig time changed with streaming: {sorted(rig_s)} s")
    return {
        "streaming_overhead": {"value": statistics.median(ratios), "unit": "ratio"},
        "streaming_capture_s": {"value": statistics.median(walls[True]), "unit": "s"},
        "plain_capture_s": {"value": statistics.median(walls[False]), "unit": "s"},
    }


if __name__ == "__main__":
    for name, fig in bench_streaming().items():
        print(f"{name}: {fig['value']:.4g} {fig['unit']}")
