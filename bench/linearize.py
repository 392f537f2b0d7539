"""Linearization throughput on 24-megapixel DNGs, against rawpy's bare decode of the same files.

``linearize_mpix_per_s``: megapixels per second through the whole pipeline, decode included:
:func:`calibration.raw.read_raw` handing LibRaw's buffer to
:func:`calibration.linearize.linearize` with what a reduction applies (black level, a per-pixel
flat field, the saturation mask, exposure, 2 × 2 superpixels and a per-pixel variance).
``linearize_vs_rawpy_decode``: time of rawpy's bare decode (open + ``raw_image_visible.copy()``)
divided by the pipeline's time on the same files (goal ≥ 0.7, issue 15).
``linearize_after_unpack_vs_decode``: what the pipeline costs beyond opening and unpacking the
file (``read_raw`` handing the buffer to a no-op) over the bare decode (goal < 0.5).
All are medians over interleaved repeats, so load from other processes hits each alike.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import rawpy

from calibration.linearize import NoiseModel, linearize
from calibration.raw import read_raw
from simulators.dng import write_dng

WIDTH, HEIGHT = 6000, 4000  # 24 MP
FILES = 3
REPEATS = 5


def _synthetic_frames(folder: Path) -> list[Path]:
    """Noisy 14-bit gradients with a small saturated patch, as uncompressed DNGs."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    paths = []
    for k in range(FILES):
        level = 600 + (2000 + 4000 * k) * (x / WIDTH) * (0.5 + y / HEIGHT)
        level += rng.standard_normal((HEIGHT, WIDTH), dtype=np.float32) * 20
        level[:200, :200] = 16383
        mosaic = np.clip(level, 0, 16383).astype(np.uint16)
        paths.append(
            write_dng(folder / f"frame{k}.dng", mosaic, black_level=512, white_level=16383,
                      exposure_s=0.01 * (k + 1), iso=100, f_number=8.0)
        )
    return paths


def _bare_decode(path: Path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        return raw.raw_image_visible.copy()


NOISE = NoiseModel(gain_e_per_dn=2.0, read_noise_dn=1.8)
FLAT = (1.0 + 0.01 * np.random.default_rng(1).standard_normal((HEIGHT, WIDTH))).astype(np.float32)


def _pipeline(path: Path) -> np.ndarray:
    return read_raw(path, lambda frame: linearize(frame, flat=FLAT, noise=NOISE)).rgb


def _unpack_only(path: Path) -> None:
    read_raw(path, lambda frame: None)


def bench_linearize() -> dict[str, dict[str, float | str]]:
    """Throughput of load + linearize, and its speed relative to rawpy's bare decode."""
    with tempfile.TemporaryDirectory(prefix="gonio-bench-") as tmp:
        paths = _synthetic_frames(Path(tmp))
        for path in paths:  # warm the page cache and the code paths
            _bare_decode(path)
            _pipeline(path)
        decode_s: list[float] = []
        pipeline_s: list[float] = []
        unpack_s: list[float] = []
        for _ in range(REPEATS):
            for path in paths:
                t0 = time.perf_counter()
                _bare_decode(path)
                t1 = time.perf_counter()
                _pipeline(path)
                t2 = time.perf_counter()
                _unpack_only(path)
                t3 = time.perf_counter()
                decode_s.append(t1 - t0)
                pipeline_s.append(t2 - t1)
                unpack_s.append(t3 - t2)
    decode = statistics.median(decode_s)
    pipeline = statistics.median(pipeline_s)
    after_unpack = statistics.median(p - u for p, u in zip(pipeline_s, unpack_s, strict=True))
    mpix = WIDTH * HEIGHT / 1e6
    return {
        "linearize_mpix_per_s": {"value": mpix / pipeline, "unit": "Mpx/s"},
        "linearize_vs_rawpy_decode": {"value": decode / pipeline, "unit": "ratio"},
        "linearize_after_unpack_vs_decode": {"value": after_unpack / decode, "unit": "ratio"},
    }


if __name__ == "__main__":
    for name, fig in bench_linearize().items():
        print(f"{name}: {fig['value']:.4g} {fig['unit']}")
