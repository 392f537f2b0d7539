"""``gonio export``: a BRDF table as MERL binary, CSV, EXR slices or an RGL ``.bsdf``."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.options import add_json, add_out, report

COMMANDS = {"export": "convert a BRDF table (HDF5, MERL or RGL .bsdf) to merl, csv, exr or bsdf"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help=COMMANDS["export"])
    p.add_argument("table", help="isotropic table (.h5), MERL file (.binary) or RGL .bsdf file")
    p.add_argument("--format", required=True, choices=[f.value for f in api.ExportFormat])
    add_out(p, "output file (EXR: folder); default beside the table", aliases=("--output",))
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    result = api.export_table(args.table, args.format, args.out)
    report(args, result, [result.line()])
    return 0
