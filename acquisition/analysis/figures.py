"""The report's figures (matplotlib, Agg): each function returns a figure, labelled with
units, one idea per figure. The caller saves or embeds it and closes it."""

from __future__ import annotations

from typing import Any

import numpy as np

from acquisition.analysis.checks import directional_albedo
from acquisition.analysis.fit import FitResult
from acquisition.analysis.render import render_sphere, table_brdf
from acquisition.geometry.halfdiff import halfdiff_from_angles
from acquisition.tables import IsotropicTable

GREEN = 1
"""Channel the single-channel figures show."""
MAX_PANELS = 8
"""Δφ bins a map shows at most (evenly chosen; the caption says which)."""


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _slice_grid(n: int) -> tuple[int, int]:
    cols = min(n, 4)
    return (n + cols - 1) // cols, cols


def map_panels(table: IsotropicTable) -> np.ndarray:
    """The Δφ bins a map shows: all, or :data:`MAX_PANELS` evenly spread."""
    n = table.shape[2]
    return np.arange(n) if n <= MAX_PANELS else np.unique(
        np.linspace(0, n - 1, MAX_PANELS).round().astype(int))


def bin_maps(table: IsotropicTable, values: np.ndarray, label: str, *, log: bool = False,
             cmap: str = "viridis", vmin: float | None = None) -> Any:
    """One (θi × θr) map per shown Δφ bin (:func:`map_panels`) of a per-bin quantity (NaN:
    not measured, grey)."""
    plt = pyplot()
    panels = map_panels(table)
    dp = table.centers()[2][panels]
    values = values[:, :, panels]
    rows, cols = _slice_grid(dp.size)
    fig, axes = plt.subplots(rows, cols, figsize=(3.1 * cols, 2.9 * rows + 0.4), squeeze=False,
                             layout="constrained")
    finite = values[np.isfinite(values)]
    norm = None
    if finite.size:
        from matplotlib.colors import LogNorm, Normalize

        lo, hi = float(finite.min()) if vmin is None else vmin, float(finite.max())
        hi = hi if hi > lo else lo + 1.0
        norm = LogNorm(max(lo, hi * 1e-6, 1e-300), hi) if log and hi > 0 else Normalize(lo, hi)
    ext = [table.theta_r_edges[0], table.theta_r_edges[-1], table.theta_i_edges[0],
           table.theta_i_edges[-1]]
    image = None
    for k, ax in enumerate(axes.ravel()):
        if k >= dp.size:
            ax.axis("off")
            continue
        ax.set_facecolor("#dddddd")
        image = ax.imshow(np.ma.masked_invalid(values[:, :, k]), origin="lower", extent=ext,
                          aspect="auto", cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_title(f"Δφ = {dp[k]:g}°", fontsize=10)
        ax.set_xlabel("θr (°)", fontsize=9)
        ax.set_ylabel("θi (°)", fontsize=9)
        ax.tick_params(labelsize=8)
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8, label=label)
    fig.get_layout_engine().set(h_pad=0.12, w_pad=0.08)
    return fig


def polar_slices(table: IsotropicTable, fit: FitResult | None = None) -> Any:
    """BRDF (green) against θr in the plane of incidence (left: the light's side, Δφ 0°;
    right: the mirror side, Δφ 180°) and across it (Δφ 90°), one polar panel per θi, radius
    log f with ticks in sr⁻¹, ±1σ error bars and the best fit's curve."""
    plt = pyplot()
    ti, tr, dp = table.centers()
    picks = np.unique(np.linspace(0, ti.size - 1, min(4, ti.size)).round().astype(int))
    planes = [("in plane (Δφ 0° | 180°)", 0.0, 180.0, "C0"),
              ("out of plane (Δφ 90°)", 90.0, 90.0, "C1")]
    fig, axes = plt.subplots(1, len(picks), subplot_kw={"projection": "polar"},
                             figsize=(3.6 * len(picks), 4.2), squeeze=False)
    mean, se = table.mean[..., GREEN], table.std_error[..., GREEN]
    positive = mean[(table.count > 0) & (mean > 0)]
    lo = np.floor(np.log10(positive.min())) if positive.size else -3.0
    hi = np.ceil(np.log10(positive.max())) if positive.size else 0.0
    for ax, i in zip(axes[0], picks, strict=True):
        for name, back, front, colour in planes:
            jb, jf = int(np.argmin(np.abs(dp - back))), int(np.argmin(np.abs(dp - front)))
            angle = np.concatenate([-np.radians(tr[::-1]), np.radians(tr)])
            y = np.concatenate([mean[i, ::-1, jb], mean[i, :, jf]])
            e = np.concatenate([se[i, ::-1, jb], se[i, :, jf]])
            ok = np.isfinite(y) & (y > 0)
            r = np.log10(y[ok]) - lo
            er = np.nan_to_num(e[ok] / (y[ok] * np.log(10)))
            ax.errorbar(angle[ok], r, yerr=er, fmt="o", ms=3.5, color=colour, label=name,
                        capsize=2, lw=0.8)
            if fit is not None:
                t = np.linspace(-np.pi / 2 * 0.98, np.pi / 2 * 0.98, 181)
                g = fit.evaluate(ti[i], np.degrees(np.abs(t)), np.where(t < 0, back, front))
                ax.plot(t, np.log10(np.maximum(g[..., GREEN], 10**lo)) - lo, "-", color=colour,
                        lw=0.9, alpha=0.7)
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)  # positive θr (mirror side) to the right
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        decades = np.arange(lo, hi + 1)
        ax.set_rlim(0, hi - lo)
        ax.set_rticks(decades[1:] - lo, [f"{10**d:g}" for d in decades[1:]], fontsize=8)
        ax.set_title(f"θi = {ti[i]:g}°", fontsize=11)
        ax.tick_params(labelsize=8)
    axes[0][0].legend(fontsize=8, loc="lower left", bbox_to_anchor=(0.0, -0.25))
    fig.suptitle("BRDF (sr⁻¹, green, log radius) against θr: left the light's side, right the "
                 "mirror side; ±1σ; lines: best fit", fontsize=11)
    fig.tight_layout()
    return fig


def halfdiff_image(table: IsotropicTable) -> Any:
    """Measured bins on (θh, θd), coloured by log₁₀ f (green), MERL style: points for a few
    hundred bins, their 2.5° average image beyond (no point hides another)."""
    plt = pyplot()
    measured = table.count > 0
    a = table.mean_angles[measured]
    th, td, _ = halfdiff_from_angles(a[:, 0], a[:, 1], a[:, 2])
    logf = np.log10(np.maximum(table.mean[measured][:, GREEN], 1e-6))
    x = np.sqrt(th / 90.0) * 90.0
    fig, ax = plt.subplots(figsize=(6, 4.8))
    if x.size <= 400:
        image = ax.scatter(x, td, c=logf, s=30, cmap="viridis", edgecolors="k", linewidths=0.3)
    else:
        from scipy.stats import binned_statistic_2d

        edges = np.arange(0.0, 92.5, 2.5)
        stat = binned_statistic_2d(x, td, logf, "mean", bins=[edges, edges]).statistic
        image = ax.imshow(np.ma.masked_invalid(stat.T), origin="lower", extent=[0, 90, 0, 90],
                          cmap="viridis", aspect="auto", interpolation="nearest")
        ax.set_facecolor("#dddddd")
    fig.colorbar(image, label="log₁₀ BRDF (sr⁻¹), green")
    ticks = np.array([0, 5, 20, 45, 90])
    ax.set_xticks(np.sqrt(ticks / 90.0) * 90.0, [f"{t}" for t in ticks])
    ax.set_xlabel("θh (°, square-root axis as in MERL)")
    ax.set_ylabel("θd (°)")
    ax.set_xlim(0, 90)
    ax.set_ylim(0, 90)
    ax.set_title(f"{int(measured.sum())} measured bins on the half/difference plane")
    fig.tight_layout()
    return fig


def albedo_plot(table: IsotropicTable) -> Any:
    """ρ(θi) per channel with its ±2σ band, and the measured fraction of the hemisphere."""
    plt = pyplot()
    alb = directional_albedo(table)
    has = alb["covered"] > 0
    t = alb["theta_i_deg"][has]
    fig, ax = plt.subplots(figsize=(6, 4))
    shift = 0.012 * (t.max() - t.min() if t.size > 1 else 10.0)
    for c, (colour, marker) in enumerate(zip(("#d62728", "#2ca02c", "#1f77b4"), "s^o",
                                             strict=True)):
        rho, u = alb["rho"][has, c], alb["u"][has, c]
        x = t + (c - 1) * shift  # grey samples: the three channels side by side, not hidden
        ax.errorbar(x, rho, yerr=2 * u, fmt=marker + "-", color=colour, ms=4, lw=0.8,
                    capsize=2, label=f"{'RGB'[c]} (±2σ)")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("θi (°)")
    ax.set_ylabel("directional albedo ρ(θi) (measured bins)")
    ax2 = ax.twinx()
    ax2.bar(t, alb["covered"][has], width=np.min(np.diff(t)) * 0.6 if t.size > 1 else 5,
            color="#999999", alpha=0.25)
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("covered fraction of the projected hemisphere")
    ax.set_title("Energy: ρ(θi) = ∫ f cos θr dωr, ±2σ (a lower bound where not covered)",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    return fig


def reciprocity_map(table: IsotropicTable) -> Any | None:
    """z = (f(θi, θr) − f(θr, θi)) / u per pair, on (θi, θr) for each Δφ bin (green); None
    when θi and θr are binned differently (no pairs)."""
    if not np.array_equal(table.theta_i_edges, table.theta_r_edges):
        return None
    u = np.sqrt(sum((t.values**2 for t in table.uncertainty_terms.values() if not t.correlated),
                    np.zeros(table.shape + (3,))))
    mean = table.mean
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (mean - np.swapaxes(mean, 0, 1)) / np.sqrt(u**2 + np.swapaxes(u, 0, 1) ** 2)
    z = z[..., GREEN]
    ii, rr = np.meshgrid(np.arange(table.shape[0]), np.arange(table.shape[1]), indexing="ij")
    z[(ii >= rr)] = np.nan
    fig = bin_maps(table, z, "z = Δf / u (reciprocal pairs, θi < θr)", cmap="coolwarm")
    for image in fig.axes[0].images:
        image.set_clim(-4, 4)
    return fig


def residual_plot(table: IsotropicTable, fits: list[FitResult]) -> Any:
    """Normalised residuals (data − model) / u against θh for each fit (green)."""
    plt = pyplot()
    measured = (table.count > 0) & np.all(np.isfinite(table.std_error), -1)
    a = table.mean_angles[measured]
    th, _, _ = halfdiff_from_angles(a[:, 0], a[:, 1], a[:, 2])
    fig, axes = plt.subplots(len(fits), 1, figsize=(7, 2.2 * len(fits) + 0.5), squeeze=False,
                             sharex=True)
    for ax, fit in zip(axes[:, 0], fits, strict=True):
        model = fit.evaluate(a[:, 0], a[:, 1], a[:, 2])[:, GREEN]
        r = (table.mean[measured][:, GREEN] - model) / table.std_error[measured][:, GREEN]
        ax.scatter(th, r, s=8, c="C0")
        ax.axhline(0, color="k", lw=0.6)
        for level in (-3, 3):
            ax.axhline(level, color="k", lw=0.5, ls=":")
        ax.set_ylabel("(f − model)/u")
        ax.set_title(f"{fit.model.name}: χ²/dof {fit.chi2_dof:.3g}", fontsize=9)
    axes[-1, 0].set_xlabel("θh (°)")
    fig.tight_layout()
    return fig


def sphere_figure(table: IsotropicTable, light_deg: tuple[float, ...] = (0.0, 30.0, 60.0),
                  size: int = 160) -> Any:
    """A sphere rendered from the table under a distant point light at several elevations
    (light in the x–z plane; tone-mapped for display: shared scale, γ 2.2)."""
    plt = pyplot()
    brdf = table_brdf(table)
    images = [render_sphere(brdf, np.array([np.sin(np.radians(e)), 0.0, np.cos(np.radians(e))]),
                            size) for e in light_deg]
    scale = max(float(np.percentile(im[im > 0], 99.5)) if (im > 0).any() else 1.0
                for im in images)
    fig, axes = plt.subplots(1, len(images), figsize=(3 * len(images), 3.2), squeeze=False)
    for ax, im, e in zip(axes[0], images, light_deg, strict=True):
        ax.imshow(np.clip(im / scale, 0, 1) ** (1 / 2.2))
        ax.set_title(f"light {e:g}° from the view", fontsize=9)
        ax.axis("off")
    fig.suptitle("A sphere of this BRDF (orthographic view, distant light)", fontsize=10)
    fig.tight_layout()
    return fig
