"""``gonio fit`` (the lecture's models, with 1σ and the metrics), ``gonio check`` (reciprocity,
energy, coverage, SNR) and ``gonio compare`` (two tables, MERL files or material specs)."""

from __future__ import annotations

import argparse
import sys

from acquisition import api
from acquisition.cli import progress
from acquisition.cli.options import add_json, add_out, report

COMMANDS = {
    "fit": "fit an analytic BRDF model to a table or session (weighted, with 1σ)",
    "check": "check a table's physics: reciprocity, energy, coverage, SNR (exit 1 on failure)",
    "compare": "compare two tables, MERL files or material specs over their common bins",
    "report": "write a self-contained HTML report of a table or session",
}

_MODELS = ("lambert", "oren-nayar", "phong", "blinn-phong", "ggx", "beckmann")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help=COMMANDS["fit"])
    p.add_argument("source", help="isotropic table (.h5) or session folder")
    p.add_argument("--model", required=True, choices=_MODELS,
                   help="ggx fits exactly the ggx: material's form (Lambert + one GGX lobe, "
                        "separable Smith, Schlick)")
    p.add_argument("--lobes", type=int, choices=(1, 2), default=1,
                   help="specular lobes (phong, blinn-phong, ggx, beckmann)")
    p.add_argument("--masking", choices=("separable", "height-correlated"), default="separable",
                   help="Smith masking of the microfacet models")
    p.add_argument("--fresnel", choices=("schlick", "dielectric", "conductor"),
                   default="schlick", help="Fresnel term of the microfacet models")
    p.add_argument("--calibration", metavar="BUNDLE",
                   help="calibration bundle to reduce a session with")
    add_json(p)
    p.set_defaults(func=run_fit)

    p = sub.add_parser("check", help=COMMANDS["check"])
    p.add_argument("source", help="isotropic table (.h5) or session folder")
    p.add_argument("--calibration", metavar="BUNDLE",
                   help="calibration bundle to reduce a session with")
    add_json(p)
    p.set_defaults(func=run_check)

    p = sub.add_parser("compare", help=COMMANDS["compare"])
    p.add_argument("a", help="reference: table (.h5), MERL file or material spec")
    p.add_argument("b", help="the other: table (.h5), MERL file or material spec")
    add_json(p)
    p.set_defaults(func=run_compare)

    p = sub.add_parser("report", help=COMMANDS["report"])
    p.add_argument("source", help="isotropic table (.h5) or session folder")
    add_out(p, "report file (.html): one self-contained file", required=True)
    p.add_argument("--models", default=",".join(api.REPORT_MODELS),
                   help="models to fit, comma-separated (default: %(default)s)")
    p.add_argument("--reference", metavar="SOURCE",
                   help="table, MERL file or material spec to compare with (default: a "
                        "simulated capture's material)")
    p.add_argument("--calibration", metavar="BUNDLE",
                   help="calibration bundle to reduce a session with")
    add_json(p)
    p.set_defaults(func=run_report)


def _value(entry: dict) -> str:
    return f"{entry['value']:.6g} ± {entry['sigma']:.2g}"


def fit_lines(result: dict) -> list[str]:
    """The text report of a fit's :meth:`FitResult.to_dict`."""
    lines = [f"{result['model']} fit to {result['bins']} bins: χ²/dof {result['chi2_dof']:.3g} "
             f"({result['dof']} dof)"]
    for name, entry in result["params"].items():
        edge = ("  (at the edge of the fit box)" if name in result["at_bound"] else
                "  (poorly constrained: 1σ exceeds the value)" if name in result["poorly_constrained"]
                else "")
        if "value" in entry:
            lines.append(f"  {name:<9} {_value(entry)}{edge}")
        else:
            lines.append(f"  {name:<9} " + "   ".join(f"{c} {_value(e)}" for c, e in entry.items())
                         + edge)
    lines.append("metrics: " + ", ".join(f"{k} {v:.4g}" for k, v in result["metrics"].items()))
    lines.append(f"material: {result['material']}")
    return lines


def run_fit(args: argparse.Namespace) -> int:
    result = api.fit(args.source, args.model, lobes=args.lobes, masking=args.masking,
                     fresnel=args.fresnel, calibration=args.calibration).to_dict()
    report(args, result, fit_lines(result))
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Exit 0 when every check passes, 1 with one line per failed check on stderr."""
    result = api.check(args.source, calibration=args.calibration)
    report(args, result.to_dict(), result.lines())
    for failed in result.failed:
        print(f"gonio: check failed: {failed.line}", file=sys.stderr)
    return 1 if result.failed else 0


def run_compare(args: argparse.Namespace) -> int:
    result = api.compare(args.a, args.b)
    report(args, result.to_dict(), result.lines())
    return 0


def run_report(args: argparse.Namespace) -> int:
    result = api.report(args.source, args.out,
                        models=tuple(m.strip() for m in args.models.split(",") if m.strip()),
                        reference=args.reference, calibration=args.calibration,
                        notice=lambda text: progress.status(f"report: {text}…"))
    for warning in result.warnings:
        print(f"gonio: warning: {warning}", file=sys.stderr)
    fits = ", ".join(f"{f.model.name} χ²/dof {f.chi2_dof:.3g}" for f in result.fits)
    report(args, {"report": result.path, "fits": [f.to_dict() for f in result.fits],
                  "checks_passed": result.checks_passed},
           [f"report: {result.path}", f"fits: {fits or 'none'}",
            "physical checks: " + ("pass" if result.checks_passed else "FAILED (see the report)")])
    return 0
