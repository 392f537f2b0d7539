"""Materials the simulated camera sees, from spec strings: the reference materials of
:mod:`simulators.materials` (``lambert:``, ``ggx:``), measured MERL files (``merl:PATH``) and
RGL-EPFL ``.bsdf`` files (``bsdf:PATH``, RGB; evaluated from their RGL fields alone).

Importing this module registers ``merl:PATH`` and ``bsdf:PATH`` in
:data:`simulators.materials.MATERIAL_PARSERS`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.formats.merl import MerlBRDF, read_merl
from acquisition.formats.rgl import RglBsdf, read_bsdf
from drivers.errors import ConfigError, MaterialError
from simulators.materials import MATERIAL_PARSERS, Material, material_from_spec

DEFAULT_MATERIAL = "ggx:albedo=0.2,alpha=0.3,f0=0.04"
"""What the simulated camera sees when no material is given: a rough dielectric GGX."""


def parse_material(spec: str) -> Material:
    """The simulated material of a spec string (``merl:PATH`` included); raises
    :class:`MaterialError` naming the problem."""
    return material_from_spec(spec)


class MerlMaterial(Material):
    """A MERL BRDF as a simulated material.

    Evaluates like :meth:`MerlBRDF.eval_vectors`, but returns 0 for directions at or below the
    horizon (the :class:`Material` contract) and for unmeasured (negative) bins.
    """

    def __init__(self, brdf: MerlBRDF, spec: str) -> None:
        self.brdf = brdf
        self.spec = spec

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        value = np.maximum(self.brdf.eval_vectors(wi, wo), 0.0)
        above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return np.where(above[..., None], value, 0.0)

    def __repr__(self) -> str:
        return f"MerlMaterial({self.spec!r})"


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
    except ConfigError as exc:
        raise MaterialError(f"material '{prefix}:{name}': {exc}") from None


def material_from_merl_spec(text: str) -> MerlMaterial:
    """Parser for ``merl:PATH`` (``text`` is PATH); raises :class:`MaterialError`."""
    brdf, name = _read_file_spec("merl", text, "/data/merl/alum-bronze.binary", read_merl)
    return MerlMaterial(brdf, f"merl:{name}")


class BsdfMaterial(Material):
    """An RGL ``.bsdf`` file as a simulated material: its BRDF as the RGL reference evaluator
    gives it (:meth:`RglBsdf.eval_vectors`), 0 at or below the horizon."""

    def __init__(self, bsdf: RglBsdf, spec: str) -> None:
        self.bsdf = bsdf
        self.spec = spec

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return self.bsdf.eval_vectors(wi, wo)

    def __repr__(self) -> str:
        return f"BsdfMaterial({self.spec!r})"


def material_from_bsdf_spec(text: str) -> BsdfMaterial:
    """Parser for ``bsdf:PATH`` (``text`` is PATH); raises :class:`MaterialError`."""
    bsdf, name = _read_file_spec("bsdf", text, "runs/s1/brdf.bsdf", read_bsdf)
    return BsdfMaterial(bsdf, f"bsdf:{name}")


MATERIAL_PARSERS["merl"] = material_from_merl_spec
MATERIAL_PARSERS["bsdf"] = material_from_bsdf_spec
