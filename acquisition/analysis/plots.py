"""Plots of BRDF tables (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from acquisition.tables import IsotropicTable  # noqa: E402


def _in_plane(table: IsotropicTable, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Signed θr (negative = same side as the light, Δφ≈0; positive = mirror side, Δφ≈180)
    and the green-channel value, for θi bin ``i``."""
    _, tr, dp = table.centers()
    j_back, j_fwd = int(np.argmin(np.abs(dp))), int(np.argmin(np.abs(dp - 180)))
    x = np.concatenate([-tr[::-1], tr])
    y = np.concatenate([table.mean[i, ::-1, j_back, 1], table.mean[i, :, j_fwd, 1]])
    return x, y


def plot_slices(
    measured: IsotropicTable, truth: IsotropicTable | None, path: str | Path, title: str = ""
) -> Path:
    """In-plane BRDF slices (measured points, truth lines) and measured-vs-truth scatter."""
    path = Path(path)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ti = measured.centers()[0]
    picks = np.unique(np.linspace(0, len(ti) - 1, min(5, len(ti))).round().astype(int))
    for n, i in enumerate(picks):
        colour = f"C{n}"
        x, y = _in_plane(measured, i)
        ax.plot(x, y, "o", color=colour, label=f"measured θi≈{ti[i]:.0f}°")
        if truth is not None:
            xt, yt = _in_plane(truth, i)
            ax.plot(xt, yt, "-", color=colour, alpha=0.7)
    ax.set_yscale("log")
    ax.set_xlabel("signed θr (°): − towards the light (Δφ=0), + mirror side (Δφ=180)")
    ax.set_ylabel("BRDF, green channel (sr⁻¹)")
    ax.set_title("In-plane slices (lines: simulated truth)")
    ax.legend(fontsize=8)
    if truth is not None:
        mask = (measured.count > 0) & (truth.count > 0)
        t, m = truth.mean[mask][:, 1], measured.mean[mask][:, 1]
        ax2.loglog(t, m, ".", ms=3)
        lo, hi = float(np.nanmin(t)), float(np.nanmax(t))
        ax2.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax2.set_xlabel("truth (sr⁻¹)")
        ax2.set_ylabel("measured (sr⁻¹)")
        ax2.set_title(f"All {int(mask.sum())} measured bins")
    else:
        ax2.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
