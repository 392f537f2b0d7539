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
    which = p.add_mutually_exclusive_group()
    which.add_argument("--ids", type=_ids, default=None,
                       help="a bare bus of servos with these IDs, e.g. 1,2,3 (default)")
    which.add_argument("--rig", help="serve this rig file's servos (IDs, baud, limits, park "
                                     "pose) with its solid parts: arms that touch stall and trip")
    p.add_argument("--baud", type=int, default=57600, help="bare bus baud rate (default 57600)")
    p.add_argument("--stall-trip-s", type=float, default=1.0,
                   help="with --rig: stall time before the overload trip (device s, default 1)")
    p.add_argument("--time-scale", type=float, default=1.0,
                   help="simulated seconds per real second (default 1)")
    add_sim_fault(p)
    p.add_argument("--fault", dest="old_fault", action="append", default=[], metavar="SPEC",
                   help="deprecated spelling of --sim-fault")
    add_seed(p)
    p.set_defaults(func=run_servos)

    p = devices.add_parser("dmx", help="an Enttec DMX USB Pro compatible widget")
    p.set_defaults(func=run_dmx)


def _announce(paths: list[str]) -> None:
    """Each device path on its own line, first on stdout; a note for the human on stderr."""
    print("\n".join(paths), flush=True)
    print(f"gonio: serving {', '.join(paths)}; Ctrl-C to stop", file=sys.stderr, flush=True)


def run_servos(args: argparse.Namespace) -> int:
    if args.old_fault:
        print("gonio: warning: --fault is deprecated: use --sim-fault", file=sys.stderr)
    faults = [*args.sim_fault, *args.old_fault]
    if args.rig:
        return api.serve_rig(args.rig, args.time_scale, faults, args.seed, ready=_announce,
                             stall_trip_s=args.stall_trip_s)
    return api.serve_servos(args.ids or [1, 2, 3], args.baud, args.time_scale, faults,
                            args.seed, ready=_announce)


def run_dmx(args: argparse.Namespace) -> int:
    return api.serve_dmx(out=sys.stdout, err=sys.stderr)
