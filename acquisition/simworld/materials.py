"""Materials the simulated camera sees, from spec strings: the reference materials of
:mod:`simulators.materials` (``lambert:``, ``ggx:``) and measured MERL files (``merl:PATH``).

Importing this module registers ``merl:PATH`` in :data:`simulators.materials.MATERIAL_PARSERS`.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from acquisition.formats.merl import MerlBRDF, read_merl
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


@functools.lru_cache(maxsize=4)
def _read_cached(resolved: str, mtime_ns: int, size: int) -> MerlBRDF:
    return read_merl(resolved)


def material_from_merl_spec(text: str) -> MerlMaterial:
    """Parser for ``merl:PATH`` (``text`` is PATH); raises :class:`MaterialError`."""
    name = text.strip()
    if not name:
        raise MaterialError(
            "material 'merl:' needs a file path, e.g. merl:/data/merl/alum-bronze.binary"
        )
    path = Path(name).expanduser()
    try:
        st = path.stat()
        brdf = _read_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)
    except FileNotFoundError:
        raise MaterialError(f"material 'merl:{name}': file {path} does not exist") from None
    except ConfigError as exc:
        raise MaterialError(f"material 'merl:{name}': {exc}") from None
    return MerlMaterial(brdf, f"merl:{name}")


MATERIAL_PARSERS["merl"] = material_from_merl_spec
