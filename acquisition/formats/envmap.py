"""Lat-long environment maps and linear EXR input/output (OpenImageIO).

Convention (sample frame, normal +z): row i of an (H, W) map is polar angle
θ = π (i + ½) / H from +z (top row = zenith), column j is azimuth φ = 2π (j + ½) / W from
+x towards +y. A pixel holds radiance (W·sr⁻¹·m⁻² or any linear unit) arriving *from* that
direction; its solid angle is the exact area of its latitude band cell,
Ω = (cos θ₀ − cos θ₁) · 2π / W (sr), so a map's Ω sum to 4π.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from drivers.errors import ConfigError, StorageError


def latlong_directions(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (H, W, 3) of every pixel centre and their solid angles (H, W), sr."""
    h, w = shape
    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), ct), axis=-1)
    edges = np.pi * np.arange(h + 1) / h
    band = (np.cos(edges[:-1]) - np.cos(edges[1:])) * 2 * np.pi / w
    return dirs, np.broadcast_to(band[:, None], (h, w)).copy()


def write_exr(path: str | Path, image: np.ndarray,
              attributes: Mapping[str, object] | None = None) -> None:
    """Write a float32 RGB EXR with typed attributes (str, int, float, float sequences)."""
    import OpenImageIO as oiio

    path = Path(path)
    data = np.ascontiguousarray(image, dtype=np.float32)
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.FLOAT)
    for key, value in (attributes or {}).items():
        if isinstance(value, str):
            spec.attribute(key, value)
        elif isinstance(value, bool | int | np.integer):
            spec.attribute(key, int(value))
        elif isinstance(value, float | np.floating):
            spec.attribute(key, float(value))
        else:
            arr = np.asarray(value, dtype=np.float32).ravel()
            spec.attribute(key, oiio.TypeDesc(f"float[{arr.size}]"), tuple(float(x) for x in arr))
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise StorageError(f"cannot write {path} ({oiio.geterror()}); check the folder is writable")
    try:
        if not out.write_image(data):
            raise StorageError(f"cannot write {path} ({out.geterror()}); check free disk space")
    finally:
        out.close()


def read_exr(path: str | Path) -> tuple[np.ndarray, dict[str, object]]:
    """An image (H, W, C) float32 and its attributes, from any file OpenImageIO reads."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ConfigError(f"cannot read image {path} ({oiio.geterror()}); check the path and format")
    try:
        spec = inp.spec()
        data = inp.read_image(oiio.FLOAT)
        attrs = {a.name: a.value for a in spec.extra_attribs}
    finally:
        inp.close()
    if data is None:
        raise ConfigError(f"cannot read pixels of {path}; the file may be truncated")
    return np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels), attrs
