"""Angle-input helpers: broadcasting to flat float64, Δφ normalisation (degrees)."""

from __future__ import annotations

import numpy as np


def fold_delta_phi(delta_phi_deg: np.ndarray | float) -> np.ndarray:
    """Fold Δφ (deg) into [0, 180] using isotropy: f(θi, θr, Δφ) = f(θi, θr, −Δφ).

    Δφ is the camera azimuth minus the light azimuth; any multiple of 360° is removed first, so
    −30 → 30, 190 → 170, 360 → 0, −0 → 0 and ±180 give 180 (the mirror plane). In IEEE double:
    d = Δφ mod 360 (``np.mod``, floor modulo), then 360 − d where d > 180.
    """
    d = np.mod(np.asarray(delta_phi_deg, dtype=np.float64), 360.0)
    return np.where(d > 180.0, 360.0 - d, d)


def wrap_delta_phi(delta_phi_deg: np.ndarray | float, start_deg: float = -180.0) -> np.ndarray:
    """Wrap Δφ (deg) into [start, start + 360) without folding: start + (Δφ − start) mod 360
    (``np.mod``; rounding can give exactly start + 360 for a Δφ just below start)."""
    d = np.asarray(delta_phi_deg, dtype=np.float64)
    return start_deg + np.mod(d - start_deg, 360.0)


def as_flat_float64(*values: np.ndarray | float) -> tuple[np.ndarray, ...]:
    """Broadcast the inputs against each other; each comes back as a 1-D float64 array."""
    return tuple(np.asarray(v, dtype=np.float64).reshape(-1) for v in np.broadcast_arrays(*values))


def contiguous(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each array C-contiguous and writeable (copied only where needed), as the compiled
    kernels take them: each kernel then compiles once, whatever the callers pass."""
    return tuple(a if a.flags.c_contiguous and a.flags.writeable else np.array(a, order="C")
                 for a in arrays)
