"""Choice of the binning implementation: compiled numba kernels or the pure numpy path.

Both give the same bins and counts and the same sums up to float rounding (see
:mod:`acquisition.tables.kernels`). ``numba`` is the default and about 2–4× faster; ``numpy``
is kept as the reference fallback. Pick one per table (``backend=`` argument) or for the
process with the environment variable ``GONIO_BINNING_BACKEND=numpy|numba``.
"""

from __future__ import annotations

import os
from types import ModuleType

from drivers.errors import ConfigError

ENV_VAR = "GONIO_BINNING_BACKEND"
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
