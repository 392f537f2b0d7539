"""Image-based (per-pixel) reduction of one 24 MP frame, against rawpy's bare decode of it.

A one-pose session of ``examples/rig-sphere-sim.toml`` with a 6000 × 4000 px sensor
(:func:`image_session._rig_24mp`: the 2 cm sphere fills 96 % of the image's height, ~2.7 M
samples of 6 M superpixels; light and camera 30° apart) is captured into a temporary folder
(~15–25 s with its two white references), then, interleaved, repeated ``REPEATS`` times:

* the bare decode: ``rawpy.imread`` and ``raw_image_visible.copy()`` of the frame's DNG — the
  least any reduction must do (LibRaw's unpack and a copy out of its buffer); no
  ``postprocess()``, whose demosaicing, colour conversion and gamma a radiometric reduction
  never uses and which would make the ratio look better than it is;
* the whole image-based reduction of that frame (:meth:`ImageReducer.reduce`, what
  ``gonio reduce`` runs: decode with the SHA-256 check, linearize with the noise model, then
  per-pixel geometry and binning into fresh MERL and isotropic tables, the budget tracked),
  with the white references read once beforehand (per session, not per frame);
* the per-pixel path alone on the already linearized frame (:meth:`ImageReducer.bin_image`:
  geometry and binning of every superpixel into both tables);
* the floor of that path (:mod:`_per_pixel_floor`: its arithmetic with none of its
  bookkeeping, the library's own compiled functions) over the same frame, on the same 2
  threads (the rows in two halves of equal work).

Figures (medians of the interleaved repeats, wall time on a shared machine):
``image_reduce_vs_decode`` = decode time / whole reduction time (goal ≥ 0.3, issue 15);
``image_per_pixel_msamples_per_s`` = samples binned per second of the per-pixel path / 1e6
(goal ≥ 60); ``image_per_pixel_floor_msamples_per_s`` the floor's rate, and
``image_per_pixel_vs_floor`` the path's rate over it (how much of the machine's arithmetic
rate the bookkeeping leaves; item 5's goal is out of reach wherever the floor itself is below
60); ``image_frame_superpixels_per_s`` = the same path's superpixels per second / 1e6;
``image_reduce_24mp_s`` and ``image_decode_24mp_s`` the two medians.

The bare decode's time depends on the process's heap: LibRaw mallocs a 48 MB buffer per frame,
which faults in ~12,000 fresh pages (~30 ms) unless a freed block of the heap can take it. A
process that only decodes pays the faults every time; between reductions the buffer may or
may not find such a block, depending on what the reduction allocated and freed. So
``image_decode_fresh_process_s`` records the same decode, median of ``REPEATS``, in a
separate process that does nothing else: a reference for the in-process figure.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rawpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import image_session  # noqa: E402  (the 24 MP rig and its poses)
from _per_pixel_floor import floor_rows  # noqa: E402

REPEATS = 5


def _capture(folder: Path) -> Path:
    """A one-pose 24 MP sphere session (plus the plan's two white references)."""
    rig = image_session._rig_24mp(folder)
    poses = image_session._phase_poses(image_session.PHASE_DEG)
    plan = image_session._write_plan(folder / "one.toml", [poses[len(poses) // 2]])
    image_session._capture(rig, plan, folder / "session")
    return folder / "session"


def _decode(path: Path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        return raw.raw_image_visible.copy()


_FRESH = """
import statistics, sys, time, rawpy
times = []
for _ in range(int(sys.argv[2])):
    t = time.perf_counter()
    with rawpy.imread(sys.argv[1]) as raw:
        raw.raw_image_visible.copy()
    times.append(time.perf_counter() - t)
print(statistics.median(times))
"""


def _fresh_decode(path: Path) -> float:
    """Median bare decode of ``path`` in a new process that only decodes (s)."""
    out = subprocess.run([sys.executable, "-c", _FRESH, str(path), str(REPEATS)],
                         capture_output=True, text=True, check=True, timeout=600)
    return float(out.stdout.strip())


def _floor_inputs(reducer: object, rec: object, image: object) -> tuple:
    """What :func:`_floor` reads: the frame's pose parameters, the columns' x and the
    minimum cosine, the rows' spans (as the path's GeometryJob computes them), the row bounds
    of two halves of equal work, the linearized frame and its white reference."""
    from acquisition.reduction.imaging import _balanced, frame_parameters
    from acquisition.reduction.sample_kernels import column_x
    from acquisition.reduction.sample_spans import row_spans

    h, w = image.valid.shape  # type: ignore[attr-defined]
    calibration, rel = reducer.reference_at(rec.step)  # type: ignore[attr-defined]
    camera, light = reducer._camera(rec, (h, w))  # type: ignore[attr-defined]
    p = frame_parameters(camera, light, reducer.rig.sample)  # type: ignore[attr-defined]
    spans = row_spans(p, (h, w))
    width = np.maximum(spans[1] - spans[0], 0)
    bounds = [int(b) for b in _balanced(width, 0, width.size, 2)]
    rgb = np.ascontiguousarray(image.rgb).reshape(h, 3 * w)  # type: ignore[attr-defined]
    var = np.ascontiguousarray(image.variance).reshape(h, 3 * w)  # type: ignore[attr-defined]
    frame = (p, column_x(p, w), float(reducer.min_cos))  # type: ignore[attr-defined]
    return (frame, spans, bounds, rgb, var,
            np.ascontiguousarray(calibration, np.float64),
            np.ascontiguousarray(rel, np.float64).reshape(3))


def _floor(inputs: tuple, pool: object) -> int:
    """The floor's pass (:func:`_per_pixel_floor.floor_rows`) over the frame, its rows in
    two halves of equal work, one on ``pool``'s thread; returns the candidates."""
    frame, spans, bounds, *args = inputs
    accs = [np.zeros((3, 24)), np.zeros((3, 24))]
    helper = pool.submit(floor_rows, frame, spans, bounds[1], bounds[2],  # type: ignore[attr-defined]
                         *args, accs[1])
    return int(floor_rows(frame, spans, bounds[0], bounds[1], *args, accs[0])) + int(
        helper.result())


def bench_image_reduce() -> dict[str, dict[str, float | str]]:
    from acquisition.reduction.fusedbinning import helper_pool
    from acquisition.reduction.image import ImageReducer
    from acquisition.reduction.point import linearize_with_variance

    with tempfile.TemporaryDirectory(prefix="gonio-bench-") as tmp:
        reducer = ImageReducer.open(_capture(Path(tmp)))
        frame = reducer.frames[0]
        dng = reducer.folder.frames_dir / str(frame[0].frame)

        def reduce() -> int:
            table, merl = reducer.new_tables()
            return sum(count for _, count, _ in reducer.reduce([frame], table, merl))

        def per_pixel(image: object) -> int:
            table, merl = reducer.new_tables()
            count = reducer.bin_image(image, frame[0], table, merl,  # type: ignore[arg-type]
                                      helper_pool())
            if count is None:
                raise RuntimeError("the 24 MP frame did not take the per-pixel path")
            return count

        image = linearize_with_variance(dng, reducer.rig, reducer.cal)
        _decode(dng), reduce(), per_pixel(image)  # warm the page cache and the kernels
        inputs = _floor_inputs(reducer, frame[0], image)
        candidates = _floor(inputs, helper_pool())  # and compile the floor
        decode_s, reduce_s, pixel_s, floor_s = [], [], [], []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            _decode(dng)
            t1 = time.perf_counter()
            samples = reduce()
            t2 = time.perf_counter()
            per_pixel(image)
            t3 = time.perf_counter()
            _floor(inputs, helper_pool())
            t4 = time.perf_counter()
            decode_s.append(t1 - t0)
            reduce_s.append(t2 - t1)
            pixel_s.append(t3 - t2)
            floor_s.append(t4 - t3)
        superpixels = image.valid.size
        fresh = _fresh_decode(dng)
    decode, whole, pixel, floor = (statistics.median(x)
                                   for x in (decode_s, reduce_s, pixel_s, floor_s))
    return {
        "image_reduce_vs_decode": {"value": decode / whole, "unit": "ratio"},
        "image_per_pixel_msamples_per_s": {"value": samples / pixel / 1e6, "unit": "Msamples/s"},
        "image_per_pixel_floor_msamples_per_s": {"value": candidates / floor / 1e6,
                                                 "unit": "Msamples/s"},
        "image_per_pixel_vs_floor": {"value": floor / pixel, "unit": "ratio"},
        "image_frame_superpixels_per_s": {"value": superpixels / pixel / 1e6, "unit": "M/s"},
        "image_reduce_24mp_s": {"value": whole, "unit": "s"},
        "image_decode_24mp_s": {"value": decode, "unit": "s"},
        "image_decode_fresh_process_s": {"value": fresh, "unit": "s"},
        "image_frame_samples": {"value": samples, "unit": "samples"},
    }


if __name__ == "__main__":
    for key, fig in bench_image_reduce().items():
        print(f"{key}: {fig['value']:.4g} {fig['unit']}")
