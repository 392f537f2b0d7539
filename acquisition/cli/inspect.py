"""``gonio inspect FILE [--json]``: what the RAW loader sees in a file."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.options import add_json, report

COMMANDS = {"inspect": "show the CFA pattern, levels and exposure of a RAW file"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help=COMMANDS["inspect"])
    p.add_argument("file", help="RAW file (DNG, NEF, CR2, ARW, ...)")
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    info = api.inspect_raw(args.file)
    report(args, info, [api.format_inspection(info)])
    return 0
