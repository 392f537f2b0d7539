"""Choice of the binning implementation: compiled numba kernels or the pure numpy path.

Both give bit-identical tables: the same bin for every sample (the MERL reference reader's,
computed with libm's sin/cos/acos/atan2 in IEEE double, see :mod:`acquisition.geometry.halfdiff`), the
same counts, exact sums and sums of squares (the same fixed-point integers,
:mod:`acquisition.tables.fixedpoint`) and the same drop tallies, on any CPU and whatever the
batch split or order (see :mod:`acquisition.tables.kernels`). ``numba`` is the default and
several times faster (``bench/binning.py``); ``numpy`` is the reference fallback. Pick
one per table (``backend=`` argument) or for the process with the environment variable
``GONIO_BINNING_BACKEND=numpy|numba``.

Importing this module sets ``NUMBA_DISABLE_INTEL_SVML=1`` in the environment, so that numba,
whoever imports it later in this process (or its children), keeps libm's math functions.
"""

from __future__ import annotations

import os
from types import ModuleType

from drivers.errors import ConfigError

ENV_VAR = "GONIO_BINNING_BACKEND"
SVML_ENV_VAR = "NUMBA_DISABLE_INTEL_SVML"
os.environ[SVML_ENV_VAR] = "1"  # numba reads it when imported: no SVML in place of libm
BACKENDS = ("numba", "numpy")

_kernels: ModuleType | None = None


def resolve_backend(backend: str | None = None) -> str:
    """``backend`` if given, else ``$GONIO_BINNING_BACKEND``, else ``"numba"``; validated."""
    name = backend if backend is not None else os.environ.get(ENV_VAR, "numba")
    name = name.strip().lower()
    if name not in BACKENDS:
        source = "backend argument" if backend is not None else ENV_VAR
        raise ConfigError(
            f"binning backend {name!r} from {source} is unknown; use 'numba' or 'numpy'"
        )
    return name


def kernels() -> ModuleType:
    """The compiled kernel module, imported on first use (importing numba takes ~0.3 s)."""
    global _kernels
    if _kernels is None:
        from acquisition.tables import kernels as module

        _kernels = module
    return _kernels
