"""The operator's console: ``gonio status|scan|jog|move|home|park|torque|reboot``.

Thin over :mod:`acquisition.devices.console`. Every command takes ``--rig``; on a rig file whose bus is
simulated, each command starts a fresh in-process simulator at the park pose (its servos live
only as long as the command), which checks the rig file and the code paths but keeps no state
between commands. Moves run under the Ctrl-C handler of :mod:`acquisition.session.interrupts`.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager

from acquisition import api
from acquisition.cli.operator import operator_output
from acquisition.cli.options import add_json, add_seed, add_sim_fault, report


def _ids(text: str) -> list[int]:
    """``1,2,5-8`` → [1, 2, 5, 6, 7, 8]."""
    out: list[int] = []
    try:
        for part in text.split(","):
            lo, dash, hi = part.strip().partition("-")
            out.extend(range(int(lo), int(hi) + 1) if dash else [int(lo)])
    except ValueError:
        raise argparse.ArgumentTypeError(f"IDs look like 1,2,5-8; got '{text}'") from None
    if not out or any(not 0 <= i <= 252 for i in out):
        raise argparse.ArgumentTypeError(f"IDs must lie within 0–252; got '{text}'")
    return sorted(set(out))


COMMANDS = {
    "status": "table of every axis: position, goal, temperature, errors",
    "scan": "find servos on the rig's ports (or --port) over baud rates",
    "jog": "move one axis by DEG degrees (the others hold)",
    "move": "move to a pose (θi, θr, Δφ in degrees)",
    "home": "move axes to 0° (their zero_tick); all if none named",
    "park": "move to the park pose (the white-reference pose)",
    "torque": "switch servo torque on or off",
    "reboot": "reboot an axis' servo to clear a hardware error",
}


def _common(p: argparse.ArgumentParser, rig_required: bool = True) -> None:
    p.add_argument("--rig", required=rig_required, help="rig file (TOML)")
    add_sim_fault(p)
    add_seed(p)
    add_json(p)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help=COMMANDS["status"])
    _common(p)
    p.set_defaults(func=run_status)

    p = sub.add_parser("scan", help=COMMANDS["scan"])
    _common(p, rig_required=False)
    p.add_argument("--port", help="scan this port instead of the rig's buses")
    p.add_argument("--bauds", type=int, nargs="+", default=None,
                   metavar="BAUD", help="baud rates to try (default: the common X-series rates)")
    p.add_argument("--ids", type=_ids, default=None,
                   help="IDs to look for, e.g. 1-8 (default: all, by broadcast ping)")
    p.set_defaults(func=run_scan)

    p = sub.add_parser("jog", help=COMMANDS["jog"])
    _common(p)
    p.add_argument("axis")
    p.add_argument("deg", type=float, help="relative move (degrees; negative allowed)")
    p.set_defaults(func=run_jog)

    p = sub.add_parser("move", help=COMMANDS["move"])
    _common(p)
    p.add_argument("--theta-i", type=float, required=True)
    p.add_argument("--theta-r", type=float, required=True)
    p.add_argument("--delta-phi", type=float, required=True)
    p.set_defaults(func=run_move)

    p = sub.add_parser("home", help=COMMANDS["home"])
    _common(p)
    p.add_argument("axes", nargs="*", metavar="AXIS")
    p.set_defaults(func=run_home)

    p = sub.add_parser("park", help=COMMANDS["park"])
    _common(p)
    p.set_defaults(func=run_park)

    p = sub.add_parser("torque", help=COMMANDS["torque"])
    _common(p)
    p.add_argument("state", choices=("on", "off"))
    p.add_argument("axes", nargs="*", metavar="AXIS", help="axes (default: all)")
    p.set_defaults(func=run_torque)

    p = sub.add_parser("reboot", help=COMMANDS["reboot"])
    _common(p)
    p.add_argument("axis")
    p.set_defaults(func=run_reboot)


@contextmanager
def _console(args: argparse.Namespace) -> Iterator[api.Console]:
    with operator_output(), api.sigint_stops_motion(), api.open_console(
            args.rig, sim_faults=args.sim_fault, seed=args.seed) as con:
        yield con


def _joints(args: argparse.Namespace, joints: dict[str, float]) -> int:
    report(args, {"joints_deg": joints},
           ["  ".join(f"{name} {deg:.2f}°" for name, deg in joints.items()) + "  (read back)"])
    return 0


def run_status(args: argparse.Namespace) -> int:
    with _console(args) as con:
        rows = con.status()
    report(args, {"axes": rows}, [api.format_status(rows)])
    return 1 if any(r.errors for r in rows) else 0


def run_scan(args: argparse.Namespace) -> int:
    ids = args.ids if args.ids is not None else api.ALL_IDS
    bauds = args.bauds or api.COMMON_BAUD_RATES
    with operator_output(), api.sigint_stops_motion():
        if args.port:
            results = [api.scan_port(args.port, bauds=bauds, ids=ids)]
        elif args.rig:
            results = api.scan_rig(args.rig, bauds=bauds, ids=ids,
                                   sim_faults=args.sim_fault, seed=args.seed)
        else:
            raise api.ConfigError("scan needs --rig RIG (scan its buses) or --port PORT")
    report(args, {"ports": results}, [api.format_scan(results)])
    return 0 if any(r.found for r in results) else 1


def run_jog(args: argparse.Namespace) -> int:
    with _console(args) as con:
        return _joints(args, con.jog(args.axis, args.deg))


def run_move(args: argparse.Namespace) -> int:
    with _console(args) as con:
        return _joints(args, con.move_pose(args.theta_i, args.theta_r, args.delta_phi))


def run_home(args: argparse.Namespace) -> int:
    with _console(args) as con:
        return _joints(args, con.home(args.axes or None))


def run_park(args: argparse.Namespace) -> int:
    with _console(args) as con:
        return _joints(args, con.park())


def run_torque(args: argparse.Namespace) -> int:
    with _console(args) as con:
        con.set_torque(args.state == "on", args.axes or None)
        names = args.axes or con.axis_names
    report(args, {"torque": args.state, "axes": names},
           [f"torque {args.state}: {', '.join(names)}"])
    return 0


def run_reboot(args: argparse.Namespace) -> int:
    with _console(args) as con:
        row = con.reboot(args.axis)
    report(args, {"rebooted": row},
           [f"rebooted axis '{row.axis}' (servo {row.servo_id}): no hardware error, torque off; "
            f"`gonio torque on` before moving"])
    return 0
