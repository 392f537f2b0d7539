"""The operator's console: ``gonio status|scan|jog|move|home|park|torque|reboot`` and
``gonio console`` (the same verbs in a shell on one connection, :mod:`acquisition.cli.shell`).

Thin over :mod:`acquisition.devices.console`. Every command takes ``--rig``; on a rig file whose
bus is simulated, each one-shot command starts a fresh in-process simulator at the park pose
(its servos live only as long as the command), which checks the rig file and the code paths
but keeps no state between commands; ``gonio console`` keeps one simulator for the session.
Moves run under the Ctrl-C handler of :mod:`acquisition.session.interrupts`; a move routed round
the other arm prints its legs first (``route: …``, or ``"route"`` in the ``--json`` object).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Mapping, Sequence
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


VERB_HELP = {
    "status": "table of every axis (position, goal, temperature, errors) and the pose they realise",
    "scan": "find servos on the rig's ports (or --port) over baud rates",
    "jog": "move one axis by DEG degrees (the others hold)",
    "move": "move to a pose (θi, θr, Δφ in degrees)",
    "home": "move to the rig's home pose ([home], default: park), or the named axes to theirs",
    "park": "move to the park pose (the white-reference pose)",
    "torque": "switch servo torque on or off",
    "reboot": "reboot an axis' servo to clear a hardware error",
}
"""The verbs of the one-shot commands and of the shell."""

COMMANDS = {
    **VERB_HELP,
    "console": "interactive shell on one connection to the rig (the same verbs; reads a "
               "script from stdin when it is not a terminal)",
}


def _connection(p: argparse.ArgumentParser, rig_required: bool = True) -> None:
    """The options that open a rig: ``--rig``, ``--sim-fault``, ``--seed``."""
    p.add_argument("--rig", required=rig_required, help="rig file (TOML)")
    add_sim_fault(p)
    add_seed(p)


def add_verbs(sub: argparse._SubParsersAction, *, connection: bool = True) -> None:
    """The verbs' parsers; with ``connection`` (the one-shot commands) each also takes the
    options that open the rig, without (the shell, already connected) only its own."""

    def verb(name: str, rig_required: bool = True) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=VERB_HELP[name], description=VERB_HELP[name])
        if connection:
            _connection(p, rig_required)
        add_json(p)
        return p

    p = verb("status")
    p.set_defaults(func=run_status)

    p = verb("scan", rig_required=False)
    if connection:
        p.add_argument("--port", help="scan this port instead of the rig's buses")
    p.add_argument("--bauds", type=int, nargs="+", default=None,
                   metavar="BAUD", help="baud rates to try (default: the common X-series rates)")
    p.add_argument("--ids", type=_ids, default=None,
                   help="IDs to look for, e.g. 1-8 (default: all, by broadcast ping)")
    p.set_defaults(func=run_scan)

    p = verb("jog")
    p.add_argument("axis")
    p.add_argument("deg", type=float, help="relative move (degrees; negative allowed)")
    p.set_defaults(func=run_jog)

    p = verb("move")
    p.add_argument("--theta-i", type=float, required=True)
    p.add_argument("--theta-r", type=float, required=True)
    p.add_argument("--delta-phi", type=float, required=True)
    p.set_defaults(func=run_move)

    p = verb("home")
    p.add_argument("axes", nargs="*", metavar="AXIS",
                   help="axes to move to their home angles (default: every axis, routed)")
    p.set_defaults(func=run_home)

    p = verb("park")
    p.set_defaults(func=run_park)

    p = verb("torque")
    p.add_argument("state", choices=("on", "off"))
    p.add_argument("axes", nargs="*", metavar="AXIS", help="axes (default: all)")
    p.set_defaults(func=run_torque)

    p = verb("reboot")
    p.add_argument("axis")
    p.set_defaults(func=run_reboot)


def register(sub: argparse._SubParsersAction) -> None:
    add_verbs(sub)
    p = sub.add_parser("console", help=COMMANDS["console"], description=COMMANDS["console"])
    _connection(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object on stdout per command (as if each had --json)")
    p.set_defaults(func=run_console)


# ---------------------------------------------------------------------- the verbs, connected
class RouteReport:
    """``Console.on_route`` for one command: prints the legs of a routed move before it starts
    (not with ``--json``) and keeps them for the JSON report."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.legs: list[dict[str, float]] = []

    def __call__(self, legs: Sequence[Mapping[str, float]]) -> None:
        self.legs = [dict(leg) for leg in legs]
        if not getattr(self.args, "json", False):
            print(api.format_route(self.legs), flush=True)


def _joints(args: argparse.Namespace, joints: dict[str, float], route: RouteReport) -> int:
    report(args, {"joints_deg": joints, "route": route.legs},
           ["  ".join(f"{name} {deg:.2f}°" for name, deg in joints.items()) + "  (read back)"])
    return 0


def _moving(move: Callable[[api.Console, argparse.Namespace], dict[str, float]]
            ) -> Callable[[api.Console, argparse.Namespace], int]:
    """A verb that moves: the route is reported before the move, the read-back after."""

    def verb(con: api.Console, args: argparse.Namespace) -> int:
        route = RouteReport(args)
        con.on_route = route
        try:
            return _joints(args, move(con, args), route)
        finally:
            con.on_route = None

    verb.__doc__ = move.__doc__
    return verb


def status_verb(con: api.Console, args: argparse.Namespace) -> int:
    """Every axis, and the pose the read-back joints realise; 1 when a servo reports an error."""
    rows = con.status()
    pose = con.pose({r.axis: r.position_deg for r in rows})
    report(args, {"axes": rows, "pose": api.pose_fields(pose)},
           [api.format_status(rows), api.format_pose(pose)])
    return 1 if any(r.errors for r in rows) else 0


def scan_verb(con: api.Console, args: argparse.Namespace) -> int:
    """Scan the open buses."""
    results = con.scan(bauds=args.bauds or api.COMMON_BAUD_RATES,
                       ids=args.ids if args.ids is not None else api.ALL_IDS)
    report(args, {"ports": results}, [api.format_scan(results)])
    return 0 if any(r.found for r in results) else 1


def torque_verb(con: api.Console, args: argparse.Namespace) -> int:
    con.set_torque(args.state == "on", args.axes or None)
    names = args.axes or con.axis_names
    report(args, {"torque": args.state, "axes": names},
           [f"torque {args.state}: {', '.join(names)}"])
    return 0


def reboot_verb(con: api.Console, args: argparse.Namespace) -> int:
    row = con.reboot(args.axis)
    report(args, {"rebooted": row},
           [f"rebooted axis '{row.axis}' (servo {row.servo_id}): no hardware error, torque off; "
            f"`gonio torque on` before moving"])
    return 0


VERBS: dict[str, Callable[[api.Console, argparse.Namespace], int]] = {
    "status": status_verb,
    "scan": scan_verb,
    "jog": _moving(lambda con, a: con.jog(a.axis, a.deg)),
    "move": _moving(lambda con, a: con.move_pose(a.theta_i, a.theta_r, a.delta_phi)),
    "home": _moving(lambda con, a: con.home(a.axes or None)),
    "park": _moving(lambda con, a: con.park()),
    "torque": torque_verb,
    "reboot": reboot_verb,
}
"""Each verb on an open console (the one-shot commands and the shell run these)."""


# ---------------------------------------------------------------------- one-shot commands
@contextmanager
def _console(args: argparse.Namespace) -> Iterator[api.Console]:
    with operator_output(), api.sigint_stops_motion(), api.open_console(
            args.rig, sim_faults=args.sim_fault, seed=args.seed, verb=args.command) as con:
        yield con


def _one_shot(args: argparse.Namespace) -> int:
    with _console(args) as con:
        return VERBS[args.command](con, args)


run_status = run_jog = run_move = run_home = run_park = run_torque = run_reboot = _one_shot


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


def run_console(args: argparse.Namespace) -> int:
    from acquisition.cli.shell import run_shell

    with operator_output(), api.open_console(args.rig, sim_faults=args.sim_fault,
                                             seed=args.seed, verb="console") as con:
        return run_shell(con, json_output=args.json)
