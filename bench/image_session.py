"""Peak memory of reducing an image-based session: it must not grow with the number of frames.

``bench_image_session()`` captures one 100-frame image-based session of a GGX sphere on the
simulated rig (``examples/rig-sphere-sim.toml`` at 300 × 300 px so the capture stays short),
then reduces it in a fresh subprocess. Memory is the growth of the process's peak resident
set (``VmHWM``, reset after the imports) over the resident set after the imports, read after
each frame: after frame 25 is the baseline of the same run, after frame 100 the figure
(tracemalloc would slow the reduction ~10×). Reported:

* ``image_session_peak_mb``: peak memory reducing 100 frames, MB;
* ``image_session_peak_25_frames_mb``: the same for 25 frames;
* ``image_session_peak_ratio_100_vs_25``: their ratio (≈ 1 when memory does not grow with
  frames; holding every sample would make it ≈ 4);
* ``image_session_samples_100_frames``: BRDF samples binned from the 100 frames.

The floor is the MERL table's accumulator (1,458,000 bins × count, Σ, Σ² per channel ≈ 82 MB)
plus one frame's arrays.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-sphere-sim.toml"
FRAMES = 100
BASELINE_FRAMES = 25

_CHILD = """
import json, sys
from acquisition.reduction.image import reduce_image_session
def status_kb(field):
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field + ":"))
# Reset the peak-RSS mark after the imports (numba's cache load peaks above the reduction's
# steady state), so VmHWM measures the reduction alone.
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")
base = status_kb("VmRSS") * 1024
peaks = {}
def progress(done, total):
    peaks[done] = status_kb("VmHWM") * 1024 - base
red = reduce_image_session(sys.argv[1], progress)
print(json.dumps({"peaks": peaks, "frames": red.frames, "samples": red.samples}))
"""


def _small_rig(folder: Path) -> Path:
    text = RIG.read_text()
    for old, new in (("width = 1000", "width = 300"), ("height = 1000", "height = 300"),
                     ("fx = 7200.0", "fx = 2160.0"), ("fy = 7200.0", "fy = 2160.0"),
                     ("roi = [200, 200, 300, 300]", "roi = [60, 60, 90, 90]"),
                     ("time_scale = 25.0", "time_scale = 200.0")):
        text = text.replace(old, new)
    path = folder / "rig.toml"
    path.write_text(text)
    return path


def _plan(folder: Path, rig: Path, frames: int = FRAMES) -> Path:
    """A list plan of exactly ``frames`` poses the planner accepts (light arc, three camera
    arcs)."""
    from acquisition import api

    cands = [[ti, tr, dp] for tr in (30, 60) for dp in (90, 180) for ti in range(3, 79, 3)]
    path = folder / "plan.toml"

    def write(poses: list[list[int]]) -> None:
        rows = ", ".join(f"[{a}, {b}, {c}]" for a, b, c in poses)
        path.write_text('format_version = 1\nname = "bench"\n[sampling]\nkind = "list"\n'
                        f'reciprocal = "both"\nposes = [{rows}]\n')

    write(cands)
    accepted = [[s.pose.theta_i, s.pose.theta_r, s.pose.delta_phi]
                for s in api.plan_sweep(path, rig).steps]
    if len(accepted) < frames:
        raise RuntimeError(f"only {len(accepted)} poses accepted, need {frames}")
    write(accepted[:frames])
    return path


def _reduce_peaks(session: Path) -> dict[str, object]:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(session)],
                         capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_image_session() -> dict[str, dict[str, float | str]]:
    from acquisition import api

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rig = _small_rig(folder)
        session = folder / "session"
        api.capture(rig, _plan(folder, rig), session, material="ggx:albedo=0.2,alpha=0.2,f0=0.2",
                    seed=1)
        run = _reduce_peaks(session)
    if run["frames"] != FRAMES:
        raise RuntimeError(f"reduced {run['frames']} frames, expected {FRAMES}")
    peaks: dict[str, float] = run["peaks"]  # type: ignore[assignment]
    full, base = peaks[str(FRAMES)], peaks[str(BASELINE_FRAMES)]
    mb = 1e-6
    return {
        "image_session_peak_mb": {"value": full * mb, "unit": "MB"},
        "image_session_peak_25_frames_mb": {"value": base * mb, "unit": "MB"},
        "image_session_peak_ratio_100_vs_25": {"value": full / base, "unit": "ratio"},
        "image_session_samples_100_frames": {"value": run["samples"], "unit": "samples"},
    }


if __name__ == "__main__":
    for key, fig in bench_image_session().items():
        print(f"{key}: {fig['value']:.6g} {fig['unit']}")
