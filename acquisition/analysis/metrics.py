"""Error metrics between a model (or another table) and measured bins, as the literature
names them. ``f`` is the reference (measured) BRDF and ``g`` the other, both (N, 3) in sr⁻¹;
``w`` the bins' solid-angle measure (:func:`acquisition.analysis.fitdata.bin_solid_angles`).

* ``ngan2005``: the cosine-weighted RMS difference √(Σ w (cos θi (g − f))² / Σ w) of Ngan,
  Durand & Matusik 2005 (the BRDF times cos θi is what reaches the eye);
* ``low2012_e1``: Löw et al. 2012's E1, √(Σ w cos θi (g − f)² / Σ w);
* ``low2012_e2``: Löw et al. 2012's E2, √(Σ w (ln(1 + g cos θi) − ln(1 + f cos θi))² / Σ w),
  which compresses the specular peak;
* ``log_rms``: √(mean ln(g / f)²) over bins where both are positive (relative error, no
  weighting).

Sums run over bins and colour channels.
"""

from __future__ import annotations

import numpy as np


def metrics(f: np.ndarray, g: np.ndarray, cos_i: np.ndarray, w: np.ndarray) -> dict[str, float]:
    """The named metrics of ``g`` against ``f`` (see the module docstring)."""
    c = np.clip(cos_i, 0.0, 1.0)[:, None]
    wt = np.broadcast_to(w[:, None], f.shape)
    total = float(wt.sum())

    def weighted_rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.sum(wt * x * x) / total)) if total > 0 else float("nan")

    positive = (f > 0) & (g > 0)
    log_ratio = np.log(g[positive] / f[positive])
    return {
        "ngan2005": weighted_rms(c * (g - f)),
        "low2012_e1": weighted_rms(np.sqrt(c) * (g - f)),
        "low2012_e2": weighted_rms(np.log1p(np.maximum(g, 0) * c) - np.log1p(np.maximum(f, 0) * c)),
        "log_rms": float(np.sqrt(np.mean(log_ratio**2))) if log_ratio.size else float("nan"),
    }
