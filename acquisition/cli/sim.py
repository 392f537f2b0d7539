"""``gonio sim servos`` / ``gonio sim dmx``: run one simulated device in the foreground.

Each prints the device path (a pseudo-terminal) as the first line of stdout and serves until
SIGINT or SIGTERM, so any client — gonio, the vendor SDK's examples, a terminal program — can
open it like a USB adapter.
"""

from __future__ import annotations

import argparse
import sys

from acquisition import api
from acquisition.cli.options import add_seed, add_sim_fault


def _ids(text: str) -> list[int]:
    try:
        ids = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--ids takes comma-separated integers, got '{text}'") from None
    if not ids or any(not 0 <= i <= 252 for i in ids) or len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"--ids needs distinct IDs in 0–252, got '{text}'")
    return ids


COMMANDS = {"sim": "run a simulated device in the foreground"}


def register(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("sim", help=COMMANDS["sim"])
    devices = sim.add_subparsers(dest="device", metavar="DEVICE")
    devices.required = True

    p = devices.add_parser("servos", help="a Dynamixel Protocol 2.0 bus of X-series servos")
    p.add_argument("--ids", type=_ids, default=[1, 2, 3], help="servo IDs, e.g. 1,2,3")
    p.add_argument("--baud", type=int, default=57600)
    p.add_argument("--time-scale", type=float, default=1.0,
                   help="simulated seconds per real second (default 1)")
    add_sim_fault(p)
    p.add_argument("--fault", dest="old_fault", action="append", default=[], metavar="SPEC",
                   help="deprecated spelling of --sim-fault")
    add_seed(p)
    p.set_defaults(func=run_servos)

    p = devices.add_parser("dmx", help="an Enttec DMX USB Pro compatible widget")
    p.set_defaults(func=run_dmx)


def run_servos(args: argparse.Namespace) -> int:
    if args.old_fault:
        print("gonio: warning: --fault is deprecated: use --sim-fault", file=sys.stderr)
    faults = [*args.sim_fault, *args.old_fault]
    return api.serve_servos(args.ids, args.baud, args.time_scale, faults, args.seed)


def run_dmx(args: argparse.Namespace) -> int:
    return api.serve_dmx(out=sys.stdout, err=sys.stderr)
