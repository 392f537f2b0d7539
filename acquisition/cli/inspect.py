"""``gonio inspect FILE [--json]``: what the RAW loader sees in a file."""

from __future__ import annotations

import argparse
import json

from acquisition import api


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="show the CFA pattern, levels and exposure of a RAW file")
    p.add_argument("file", help="RAW file (DNG, NEF, CR2, ARW, ...)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    info = api.inspect_raw(args.file)
    print(json.dumps(info) if args.json else api.format_inspection(info))
    return 0
