"""Materials the simulated camera sees, from spec strings: the reference materials of
:mod:`simulators.materials` (``lambert:``, ``ggx:``, …), measured MERL files (``merl:PATH``)
and RGL-EPFL ``.bsdf`` files (``bsdf:PATH``, RGB).

The files are read and evaluated by the simulator's own code (:mod:`simulators.measured`),
never by gonio's readers (``acquisition.formats``) and half/difference coordinates
(``acquisition.geometry.halfdiff``), which the reduction's MERL table and the exporters use:
a bug there must show in a capture-and-reduce round trip, not cancel out.

Importing this module registers ``merl:PATH`` and ``bsdf:PATH`` in
:data:`simulators.materials.MATERIAL_PARSERS`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivers.errors import MaterialError
from simulators.materials import MATERIAL_PARSERS, Material, material_from_spec
from simulators.measured.merl import MerlMaterial, read_merl_file
from simulators.measured.rgl import RglMaterial, read_rgl_file

__all__ = ["DEFAULT_MATERIAL", "MerlMaterial", "RglMaterial", "parse_material"]

DEFAULT_MATERIAL = "ggx:albedo=0.2,alpha=0.3,f0=0.04"
"""What the simulated camera sees when no material is given: a rough dielectric GGX."""


def parse_material(spec: str) -> Material:
    """The simulated material of a spec string (``merl:PATH`` included); raises
    :class:`MaterialError` naming the problem."""
    return material_from_spec(spec)


@functools.lru_cache(maxsize=8)
def _read_cached(read: Callable[[str], Any], resolved: str, mtime_ns: int, size: int) -> Any:
    return read(resolved)


def _read_file_spec(prefix: str, text: str, example: str, read: Callable[[str], Any]
                    ) -> tuple[Any, str]:
    """The file a ``PREFIX:PATH`` spec names, read once per (path, mtime, size); raises
    :class:`MaterialError` naming the spec and the problem."""
    name = text.strip()
    if not name:
        raise MaterialError(f"material '{prefix}:' needs a file path, e.g. {prefix}:{example}")
    path = Path(name).expanduser()
    try:
        st = path.stat()
        return _read_cached(read, str(path.resolve()), st.st_mtime_ns, st.st_size), name
    except FileNotFoundError:
        raise MaterialError(f"material '{prefix}:{name}': file {path} does not exist") from None
    except MaterialError as exc:
        raise MaterialError(f"material '{prefix}:{name}': {exc}") from None


def material_from_merl_spec(text: str) -> MerlMaterial:
    """Parser for ``merl:PATH`` (``text`` is PATH); raises :class:`MaterialError`."""
    merl, name = _read_file_spec("merl", text, "/data/merl/alum-bronze.binary", read_merl_file)
    return MerlMaterial(merl, f"merl:{name}")


def material_from_bsdf_spec(text: str) -> RglMaterial:
    """Parser for ``bsdf:PATH`` (``text`` is PATH); raises :class:`MaterialError`."""
    rgl, name = _read_file_spec("bsdf", text, "runs/s1/brdf.bsdf", read_rgl_file)
    return RglMaterial(rgl, f"bsdf:{name}")


MATERIAL_PARSERS["merl"] = material_from_merl_spec
MATERIAL_PARSERS["bsdf"] = material_from_bsdf_spec
