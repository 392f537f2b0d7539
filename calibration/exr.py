"""Linear float32 OpenEXR files through OpenImageIO: the one EXR writer and reader of gonio.

:func:`write_exr` writes through :func:`drivers.storage.atomic_output`: OpenImageIO's open,
write and close results are all checked (a full disk often shows only at close) and the file
is re-opened and read back before it is renamed into place. Attributes are typed: str, int
(and bool), float, or a sequence of numbers (``float[n]``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers.errors import ConfigError
from drivers.storage import Ours, WriteFailed, atomic_output


def _spec(oiio: Any, arr: np.ndarray, attributes: Mapping[str, object],
          channels: Sequence[str] | None, compression: str | None) -> Any:
    h, w, c = arr.shape
    spec = oiio.ImageSpec(w, h, c, oiio.FLOAT)
    if channels is not None:
        spec.channelnames = tuple(channels)
    if compression is not None:
        spec.attribute("compression", compression)
    for key, value in attributes.items():
        if isinstance(value, str):
            spec.attribute(key, value)
        elif isinstance(value, bool | int | np.integer):
            spec.attribute(key, int(value))
        elif isinstance(value, float | np.floating):
            spec.attribute(key, float(value))
        else:
            vals = np.asarray(value, dtype=np.float32).ravel()
            spec.attribute(key, oiio.TypeDesc(f"float[{vals.size}]"), [float(x) for x in vals])
    return spec


def write_exr(path: str | os.PathLike[str], image: np.ndarray,
              attributes: Mapping[str, object] | None = None, *, what: str = "EXR image",
              channels: Sequence[str] | None = None, compression: str | None = None,
              ours: Ours = None, inputs: Iterable[str | os.PathLike[str]] = (),
              own_session: bool = False) -> Path:
    """Write an H×W (or H×W×C) image as float32 EXR, atomically and verified.

    ``ours`` tells a previous output of this kind (which may be replaced) from any other
    existing file (refused), see :func:`drivers.storage.check_output`.
    """
    import OpenImageIO as oiio

    arr = np.ascontiguousarray(image, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    spec = _spec(oiio, arr, attributes or {}, channels, compression)

    def verify(tmp: Path) -> None:
        back, _ = read_exr(tmp)
        if back.shape[:2] != arr.shape[:2] or back.shape[2] != arr.shape[2]:
            raise ValueError(f"read back {back.shape}, wrote {arr.shape}")

    with atomic_output(path, what=what, verify=verify, ours=ours, inputs=inputs,
                       own_session=own_session) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise WriteFailed(oiio.geterror() or "OpenImageIO cannot create an EXR")
        wrote = out.write_image(arr)
        error = out.geterror()
        closed = out.close()
        if not (wrote and closed):
            raise WriteFailed(error or out.geterror() or "OpenImageIO failed to write the EXR")
    return Path(path)


def read_exr(path: str | os.PathLike[str]) -> tuple[np.ndarray, dict[str, Any]]:
    """An image (H, W, C) float32 and all its attributes; :class:`ConfigError` if unreadable."""
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


def exr_attribute(path: str | os.PathLike[str], name: str) -> object | None:
    """The attribute ``name`` of the image at ``path``, or None (also when it is no image)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear it
        return None
    try:
        found = inp.spec().getattribute(name)
    finally:
        inp.close()
    return found


def exr_has(name: str, value: object | None = None) -> Ours:
    """A recogniser of images carrying attribute ``name`` (equal to ``value`` when given)."""
    def ours(path: Path) -> bool:
        found = exr_attribute(path, name)
        return found is not None and (value is None or found == value)
    return ours
