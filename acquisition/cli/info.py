"""``gonio info``: a session folder's progress, timing, errors and drift, or a table's
coverage; ``gonio verify``: whether a session folder can be trusted."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition import api
from acquisition.cli.options import add_json, report

COMMANDS = {
    "info": "summarise a session folder or a BRDF table (HDF5 or MERL)",
    "verify": "re-hash a session's frames against its journal and check the journal",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help=COMMANDS["info"])
    p.add_argument("path", help="session folder, isotropic table (.h5) or MERL file (.binary)")
    p.add_argument("--no-drift", action="store_true",
                   help="skip reading the white-reference frames (faster on big sessions)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip re-hashing the frames (faster on big sessions)")
    add_json(p)
    p.set_defaults(func=run)

    p = sub.add_parser("verify", help=COMMANDS["verify"])
    p.add_argument("session", help="session folder")
    add_json(p)
    p.set_defaults(func=run_verify)


def run(args: argparse.Namespace) -> int:
    path = Path(args.path)
    if not path.exists():
        raise api.ConfigError(f"{path} does not exist: give a session folder, an isotropic "
                              "table (.h5), a MERL .binary or an RGL .bsdf file")
    if path.is_dir():
        status = api.session_status(path, drift=not args.no_drift, verify=not args.no_verify)
        report(args, status.to_json(), status.lines())
    else:
        info = api.table_info(path)
        report(args, info, info.lines())
    return 0


def run_verify(args: argparse.Namespace) -> int:
    """Exit 0 when every frame matches and the journal is sound, else 1."""
    result = api.verify_session(args.session)
    report(args, result.to_json(), result.lines())
    return 0 if result.ok else 1
