"""Peak memory of reducing an image-based session of 24 MP frames: it must not grow with frames.

``bench_image_session()`` works on ``examples/rig-sphere-sim.toml`` with its sensor made
6000 × 4000 px (24 MP) in a temporary rig file: the intrinsics and the region of interest
scale with it (× 4, so the 2 cm sphere fills the same 96 % of the image's height), and
``time_scale`` is 200 so the arms' motion costs little host time.

Every pose of the plan puts the light and the camera 30° apart (``PHASE_DEG``; the arms go
all over, Δφ 0–180°). On a sphere the lit, visible part, and so the number of samples
(~2.7 M per frame), depends on that angle alone, so frames 26–100 are no larger than frames
1–25 and the ratio below measures memory kept across frames, not the size of the largest
frame. (With a plan of varied angles, frames 45–52 had 30 % more samples than any of frames
1–25 and raised the ratio to 1.12, while the resident set after each frame had no trend.)

1. A probe: a 3-pose session is captured and reduced in a fresh subprocess, timing each frame
   (host wall time, medians): ``image_frame_capture_24mp_s`` (move, render, expose, write the
   DNG and check it, per sample frame) and ``image_frame_reduce_24mp_s`` (decode, linearize,
   per-pixel geometry, binning into both tables), with ``image_frame_samples_24mp`` (samples
   per frame) and ``image_frame_reduce_24mp_peak_mb`` (memory while reducing the white
   references and the first frame). ``image_session_projected_s``: what the 100-frame
   session would take at those speeds.
2. If that fits the budget (``GONIO_BENCH_IMAGE_BUDGET_S``, default 300 s), a 100-frame
   session is captured and reduced in a fresh subprocess. Memory is the growth of the
   process's peak resident set (``VmHWM``, reset after the imports) over the resident set
   after the imports, read after each frame: after frame 25 is the baseline of the same run,
   after frame 100 the figure (tracemalloc would slow the reduction ~10×). Reported:
   ``image_session_peak_100_frames_mb``, ``image_session_peak_25_frames_mb``,
   ``image_session_peak_ratio`` (their ratio; goal ≤ 1.05, issue 15) and
   ``image_session_samples_100_frames``. Over the budget the session is skipped, said on
   stderr, and these figures are absent rather than measured on smaller frames.

The floor is the MERL table's accumulator (1,458,000 bins × count, Σ, Σ² per channel ≈ 82 MB)
plus one 24 MP frame's transient arrays (the per-pixel geometry of 6 M superpixels alone is
~0.6 GB of float64; ~1.6–1.8 GB in all today). Between frames 25 and 100 the reduction sees
~200 M samples, so keeping as little as half a byte per sample would exceed the 1.05 goal.
The session's DNGs take 48 MB each (~5 GB for 102 frames) in a temporary folder.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-sphere-sim.toml"
FRAMES = 100
BASELINE_FRAMES = 25
PROBE_POSES = 3
REFERENCES = 2  # the plan's white references: first and last
BUDGET_S = float(os.environ.get("GONIO_BENCH_IMAGE_BUDGET_S", "300"))
MATERIAL = "ggx:albedo=0.2,alpha=0.2,f0=0.2"
PHASE_DEG = 30.0  # angle between the light and camera directions in every frame

_CHILD = """
import json, sys, time
from acquisition.reduction.image import reduce_image_session
def status_kb(field):
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field + ":"))
# Reset the peak-RSS mark after the imports (numba's cache load peaks above the reduction's
# steady state), so VmHWM measures the reduction alone.
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")
base = status_kb("VmRSS") * 1024
peaks, times = {}, {}
def progress(done, total):
    peaks[done] = status_kb("VmHWM") * 1024 - base
    times[done] = time.monotonic()
red = reduce_image_session(sys.argv[1], progress)
print(json.dumps({"peaks": peaks, "times": times, "frames": red.frames, "samples": red.samples}))
"""


def _rig_24mp(folder: Path) -> Path:
    """The sphere rig with a 6000 × 4000 px sensor, its intrinsics and ROI scaled alike."""
    text = RIG.read_text()
    for old, new in (("width = 1000", "width = 6000"), ("height = 1000", "height = 4000"),
                     ("fx = 7200.0", "fx = 28800.0"), ("fy = 7200.0", "fy = 28800.0"),
                     ("roi = [200, 200, 300, 300]", "roi = [1300, 800, 1700, 1200]"),
                     ("time_scale = 25.0", "time_scale = 200.0")):
        if old not in text:
            raise RuntimeError(f"{RIG} no longer has '{old}': update bench/image_session.py")
        text = text.replace(old, new)
    path = folder / "rig-24mp.toml"
    path.write_text(text)
    return path


def _phase_poses(phase_deg: float) -> list[list[float]]:
    """Candidate (θi, θr, Δφ) poses, deg, whose light and camera directions are ``phase_deg``
    apart: cos α = sin θi sin θr cos Δφ + cos θi cos θr, solved for θr."""
    cos_phase = math.cos(math.radians(phase_deg))
    poses = []
    for dphi in range(0, 181, 15):
        for ti in (2.5 * k for k in range(34)):
            a = math.cos(math.radians(ti))
            b = math.sin(math.radians(ti)) * math.cos(math.radians(dphi))
            if cos_phase > math.hypot(a, b):
                continue
            for sign in (1, -1):
                tr = math.degrees(math.atan2(b, a) + sign * math.acos(cos_phase / math.hypot(a, b)))
                if 0.5 <= tr <= 85.0:
                    poses.append([ti, round(tr, 4), float(dphi)])
    return poses


def _accepted_poses(folder: Path, rig: Path, frames: int = FRAMES) -> list[list[float]]:
    """``frames`` poses at PHASE_DEG the planner accepts, spread over its route."""
    from acquisition import api

    plan = _write_plan(folder / "candidates.toml", _phase_poses(PHASE_DEG))
    accepted = [[s.pose.theta_i, s.pose.theta_r, s.pose.delta_phi]
                for s in api.plan_sweep(plan, rig).steps]
    if len(accepted) < frames:
        raise RuntimeError(f"only {len(accepted)} poses accepted, need {frames}")
    return accepted[:: len(accepted) // frames][:frames]


def _plan(folder: Path, rig: Path, frames: int = FRAMES) -> Path:
    """A list plan of ``frames`` accepted poses (``folder/plan.toml``)."""
    return _write_plan(folder / "plan.toml", _accepted_poses(folder, rig, frames))


def _write_plan(path: Path, poses: list[list[float]]) -> Path:
    rows = ", ".join(f"[{a}, {b}, {c}]" for a, b, c in poses)
    path.write_text('format_version = 1\nname = "bench"\n[sampling]\nkind = "list"\n'
                    f'reciprocal = "both"\nposes = [{rows}]\n')
    return path


def _capture(rig: Path, plan: Path, session: Path) -> list[float]:
    """Capture the plan; host seconds of each sample frame (not the first step, which
    includes opening the devices, nor the white references)."""
    from acquisition import api
    from acquisition.session.engine import REFERENCE

    stamps: list[tuple[float, str]] = []
    api.capture(rig, plan, session, material=MATERIAL, seed=1,
                progress=lambda done, total, rec: stamps.append((time.monotonic(), rec.kind)))
    return [t - prev for (prev, _), (t, kind) in zip(stamps, stamps[1:], strict=False)
            if kind != REFERENCE]


def _reduce(session: Path) -> dict[str, object]:
    """Reduce in a fresh process: peak memory and clock after each frame, frames, samples."""
    out = subprocess.run([sys.executable, "-c", _CHILD, str(session)],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _frame_seconds(run: dict[str, object]) -> list[float]:
    """Seconds per frame after the first (whose time includes the white references)."""
    times: dict[str, float] = run["times"]  # type: ignore[assignment]
    stamps = [times[str(k)] for k in range(1, len(times) + 1)]
    return [b - a for a, b in zip(stamps, stamps[1:], strict=False)]


def _probe(folder: Path, rig: Path, poses: list[list[float]]) -> dict[str, float]:
    """Per-frame capture and reduction time, samples and peak memory of one 24 MP frame."""
    plan = _write_plan(folder / "probe.toml", poses[:: math.ceil(len(poses) / PROBE_POSES)])
    capture_s = _capture(rig, plan, folder / "probe")
    run = _reduce(folder / "probe")
    peaks: dict[str, float] = run["peaks"]  # type: ignore[assignment]
    return {"capture_s": statistics.median(capture_s),
            "reduce_s": statistics.median(_frame_seconds(run)),
            "samples": run["samples"] / run["frames"],  # type: ignore[operator]
            "peak_b": peaks["1"]}


def _session(folder: Path, rig: Path, poses: list[list[float]]) -> dict[str, object]:
    session = folder / "session"
    _capture(rig, _write_plan(folder / "plan.toml", poses), session)
    run = _reduce(session)
    if run["frames"] != FRAMES:
        raise RuntimeError(f"reduced {run['frames']} frames, expected {FRAMES}")
    return run


def bench_image_session() -> dict[str, dict[str, float | str]]:
    mb = 1e-6
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rig = _rig_24mp(folder)
        poses = _accepted_poses(folder, rig)
        probe = _probe(folder, rig, poses)
        projected = (FRAMES + REFERENCES) * probe["capture_s"] + FRAMES * probe["reduce_s"]
        figures: dict[str, dict[str, float | str]] = {
            "image_frame_capture_24mp_s": {"value": probe["capture_s"], "unit": "s"},
            "image_frame_reduce_24mp_s": {"value": probe["reduce_s"], "unit": "s"},
            "image_frame_samples_24mp": {"value": probe["samples"], "unit": "samples"},
            "image_frame_reduce_24mp_peak_mb": {"value": probe["peak_b"] * mb, "unit": "MB"},
            "image_session_projected_s": {"value": projected, "unit": "s"},
        }
        if projected > BUDGET_S:
            print(f"image_session_peak_ratio not measured: {FRAMES} frames of 24 MP would take "
                  f"~{projected:.0f} s here ({probe['capture_s']:.1f} s capture + "
                  f"{probe['reduce_s']:.1f} s reduction per frame), over the {BUDGET_S:.0f} s "
                  "budget; set GONIO_BENCH_IMAGE_BUDGET_S higher to measure it anyway",
                  file=sys.stderr)
            return figures
        run = _session(folder, rig, poses)
    peaks: dict[str, float] = run["peaks"]  # type: ignore[assignment]
    full, base = peaks[str(FRAMES)], peaks[str(BASELINE_FRAMES)]
    return figures | {
        "image_session_peak_100_frames_mb": {"value": full * mb, "unit": "MB"},
        "image_session_peak_25_frames_mb": {"value": base * mb, "unit": "MB"},
        "image_session_peak_ratio": {"value": full / base, "unit": "ratio"},
        "image_session_samples_100_frames": {"value": run["samples"], "unit": "samples"},
    }


if __name__ == "__main__":
    for key, fig in bench_image_session().items():
        print(f"{key}: {fig['value']:.6g} {fig['unit']}")
