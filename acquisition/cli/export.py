"""``gonio export``: a BRDF table as MERL binary, CSV or EXR slices."""

from __future__ import annotations

import argparse

from acquisition import api


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="convert a BRDF table (HDF5 or MERL) to merl, csv or exr")
    p.add_argument("table", help="isotropic table (.h5) or MERL file (.binary)")
    p.add_argument("--format", required=True, choices=[f.value for f in api.ExportFormat])
    p.add_argument("-o", "--output", help="output file (EXR: folder); default beside the table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out, n = api.export_table(args.table, args.format, args.output)
    what = "images" if args.format == api.ExportFormat.EXR else "measured bins"
    print(f"{out}: {n} {what}")
    return 0
