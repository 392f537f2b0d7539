"""The HTML report of a table or session: one self-contained file (styles inline, figures as
embedded PNG, no script, nothing fetched), readable offline in any browser.

Sections: what was measured (rig, plan, material, planned vs actual time, drift, noise model,
warnings) · physical checks · coverage and count maps · SNR map · the uncertainty budget (each
term's median relative size) · polar slices with error bars · the θh–θd plane · directional
albedo with its band · reciprocity map · fits (parameter table with 1σ, residuals) ·
comparison (against a reference, or the simulated material) · a lit sphere rendered from the
table.
"""

from __future__ import annotations

import base64
import html
import io
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.analysis import figures
from acquisition.analysis.checks import Check, check_table
from acquisition.analysis.compare import Comparison
from acquisition.analysis.fit import FitResult
from acquisition.tables import IsotropicTable
from drivers.storage import atomic_output

MARK = '<meta name="generator" content="gonio report">'
"""In every report's head: a later report may replace it, nothing else is overwritten."""
WHAT = "report"

_STYLE = """
body{font:15px/1.45 system-ui,sans-serif;margin:0 auto;max-width:1100px;padding:1em 2em;
color:#222;background:#fff}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;
text-align:left;font-variant-numeric:tabular-nums}th{background:#f3f3f3}
img{max-width:100%;height:auto;display:block;margin:.5em 0}
.pass{color:#1a7f37;font-weight:600}.fail{color:#b42318;font-weight:600}.muted{color:#666}
figure{margin:0}figcaption{color:#555;font-size:.9em}
"""


def is_report(path: str | Path) -> bool:
    """True for a report gonio wrote (it may be replaced)."""
    try:
        with open(path, "rb") as fh:
            return MARK.encode() in fh.read(4096)
    except OSError:
        return False


@dataclass
class ReportData:
    """What a report shows; only ``table`` is required."""

    table: IsotropicTable
    title: str
    measured: Mapping[str, Any] = field(default_factory=dict)
    """What was measured, label → value (rendered as a two-column table)."""
    warnings: list[str] = field(default_factory=list)
    fits: list[FitResult] = field(default_factory=list)
    fit_errors: list[str] = field(default_factory=list)
    comparison: Comparison | None = None
    checks: list[Check] = field(default_factory=list)


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=96)
    figures.pyplot().close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(fig: Any, alt: str, caption: str) -> str:
    return (f'<figure><img src="data:image/png;base64,{_png(fig)}" alt="{html.escape(alt)}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _rows(rows: Iterable[Iterable[Any]], header: Iterable[str] | None = None) -> str:
    head = ("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr>"
            if header else "")
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table>{head}{body}</table>"


def _value(v: float, s: float) -> str:
    return f"{v:.5g} ± {s:.2g}"


def _fit_table(fits: list[FitResult]) -> str:
    rows = []
    for fit in fits:
        for p in fit.model.params:
            v, s = fit.params[p.name], fit.sigma[p.name]
            shown = ("R " + " · G ".join(_value(float(a), float(b)) for a, b in
                                        zip(np.atleast_1d(v)[:2], np.atleast_1d(s)[:2], strict=True))
                     + " · B " + _value(float(np.atleast_1d(v)[2]), float(np.atleast_1d(s)[2]))
                     if p.per_channel else _value(float(v), float(s)))
            if p.name in fit.at_bound:
                shown += " (at the edge of the fit box)"
            elif p.name in fit.poorly_constrained:
                shown += " (poorly constrained)"
            rows.append((fit.model.name, p.name + (f" ({p.unit})" if p.unit else ""), shown))
        rows.append((fit.model.name, "χ²/dof (dof)", f"{fit.chi2_dof:.4g} ({fit.dof})"))
        rows.append((fit.model.name, "metrics",
                     ", ".join(f"{k} {v:.3g}" for k, v in fit.metrics.items())))
    return _rows(rows, ("model", "parameter", "value ± 1σ"))


def _checks_html(checks: list[Check]) -> str:
    items = []
    for c in checks:
        style = "" if c.passed is None else ' class="pass"' if c.passed else ' class="fail"'
        items.append(f"<li{style}>{html.escape(c.line)}</li>")
    return "<ul>" + "".join(items) + "</ul>"


def _comparison_html(cmp: Comparison) -> str:
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(5, 4.5))
    a, b = cmp.values_a[:, figures.GREEN], cmp.values_b[:, figures.GREEN]
    ax.loglog(a, b, "o", ms=3)
    lo, hi = float(min(a.min(), b.min())), float(max(a.max(), b.max()))
    ax.plot([lo, hi], [lo, hi], "k-", lw=0.7)
    ax.set_xlabel(f"A: {cmp.a.label[:40]} (sr⁻¹)")
    ax.set_ylabel(f"B: {cmp.b.label[:40]} (sr⁻¹)")
    ax.set_title(f"{cmp.bins} common bins, green", fontsize=9)
    fig.tight_layout()
    return ("<p>" + "<br>".join(html.escape(line) for line in cmp.lines()) + "</p>"
            + _figure(fig, "comparison scatter", "Each common bin: B against A (log axes)."))


def _spans_decades(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values) & (values > 0)]
    return bool(finite.size) and finite.max() / finite.min() > 30


def _panels_note(table: IsotropicTable) -> str:
    shown = figures.map_panels(table)
    return "" if shown.size == table.shape[2] else (
        f" ({shown.size} of the {table.shape[2]} Δφ bins, evenly spread)")


def _reciprocity_html(table: IsotropicTable) -> str:
    fig = figures.reciprocity_map(table)
    if fig is None:
        return '<p class="muted">θi and θr are binned differently: no reciprocal pairs.</p>'
    return _figure(fig, "reciprocity map",
                   "z-score of f(θi, θr) − f(θr, θi) for every pair measured both ways"
                   + _panels_note(table) + ".")


def budget_rows(table: IsotropicTable) -> list[tuple[str, str, str, str, str]]:
    """One row per term of the table's uncertainty budget: name, correlated or independent,
    its median and 90th-percentile size relative to the value over the measured bins (green),
    and what it is."""
    mean = table.mean[..., figures.GREEN]
    measured = (table.count > 0) & np.isfinite(mean) & (mean != 0)
    rows = []
    for name, term in table.uncertainty_terms.items():
        rel = np.abs(term.values[..., figures.GREEN][measured] / mean[measured])
        rel = rel[np.isfinite(rel)]
        median, p90 = ((f"{np.median(rel) * 100:.3g} %", f"{np.percentile(rel, 90) * 100:.3g} %")
                       if rel.size else ("–", "–"))
        rows.append((name, "correlated" if term.correlated else "independent", median, p90,
                     term.description))
    return rows


def _budget_html(table: IsotropicTable) -> str:
    rows = budget_rows(table)
    if not rows:
        return '<p class="muted">The table carries no uncertainty budget (a version-1 table).</p>'
    return (_rows(rows, ("term", "between bins", "median u/f", "90 % of bins below", "what"))
            + '<p class="muted">Each term\'s standard uncertainty relative to the bin\'s value '
              "(green channel) over the measured bins; std_error is their root sum of "
              "squares.</p>")


def build_html(data: ReportData) -> str:
    """The report's HTML text."""
    t = data.table
    count = t.count.astype(float)
    count[count == 0] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        snr = np.min(t.mean / t.std_error, axis=-1)
    best = min(data.fits, key=lambda f: f.chi2_dof) if data.fits else None
    parts = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">', MARK,
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(data.title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(data.title)}</h1>",
        f'<p class="muted">gonio report written {time.strftime("%Y-%m-%d %H:%M:%S %Z")}</p>',
        "<h2>What was measured</h2>", _rows(data.measured.items()),
    ]
    if data.warnings:
        parts.append("<p><b>Warnings</b></p><ul>" + "".join(
            f"<li>{html.escape(w)}</li>" for w in data.warnings) + "</ul>")
    parts += ["<h2>Physical checks</h2>", _checks_html(data.checks),
              "<h2>Coverage</h2>",
              _figure(figures.bin_maps(t, count, "samples per bin", log=_spans_decades(count),
                                       vmin=None if _spans_decades(count) else 0.0),
                      "count maps", "Samples per bin on (θi, θr), one panel per Δφ bin"
                      + _panels_note(t) + "; grey: not measured."),
              "<h2>Signal to noise</h2>",
              _figure(figures.bin_maps(t, snr, "SNR = f / std_error (lowest channel)", log=True),
                      "SNR maps", "Each bin's mean over its standard uncertainty (log colour)"
                      + _panels_note(t) + "."),
              "<h2>Uncertainty budget</h2>", _budget_html(t),
              "<h2>Slices</h2>",
              _figure(figures.polar_slices(t, best), "polar slices",
                      "BRDF against θr in and across the plane of incidence, ±1σ."),
              _figure(figures.halfdiff_image(t), "half/difference plane",
                      "Measured bins on (θh, θd), log colour (MERL style)."),
              "<h2>Energy</h2>",
              _figure(figures.albedo_plot(t), "directional albedo",
                      "ρ(θi) over the measured bins with ±2σ error bars; grey bars: covered "
                      "fraction of the projected hemisphere."),
              "<h2>Reciprocity</h2>", _reciprocity_html(t)]
    parts.append("<h2>Fits</h2>")
    if data.fits:
        parts += [_fit_table(data.fits),
                  _figure(figures.residual_plot(t, data.fits), "fit residuals",
                          "Normalised residuals of each fit against θh (dotted: ±3).")]
    parts += [f'<p class="muted">{html.escape(e)}</p>' for e in data.fit_errors]
    if data.comparison is not None:
        parts += ["<h2>Comparison</h2>", _comparison_html(data.comparison)]
    parts += ["<h2>Rendered</h2>",
              _figure(figures.sphere_figure(t), "lit sphere",
                      "A sphere rendered from the table (interpolated between bins)."),
              "</body></html>"]
    return "\n".join(parts)


def report_data(table: IsotropicTable, title: str, *, measured: Mapping[str, Any] | None = None,
                warnings: Iterable[str] = (), fits: Iterable[FitResult] = (),
                fit_errors: Iterable[str] = (), comparison: Comparison | None = None
                ) -> ReportData:
    """Gather a report's data; the checks are run here."""
    return ReportData(table, title, dict(measured or {}), list(warnings), list(fits),
                      list(fit_errors), comparison, check_table(table))


def write_report(text: str, path: str | Path, *, inputs: Iterable[str | Path] = ()) -> Path:
    """Write the report through the one writer (an earlier report may be replaced)."""
    path = Path(path)

    def verify(tmp: Path) -> None:
        data = tmp.read_bytes()
        if not data.startswith(b"<!DOCTYPE html>") or not data.rstrip().endswith(b"</html>"):
            raise ValueError("not a whole HTML file")

    with atomic_output(path, what=WHAT, verify=verify, ours=is_report, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
