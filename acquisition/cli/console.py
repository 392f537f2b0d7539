"""The operator's console: ``gonio status|scan|jog|move|home|park|torque|reboot``.

Thin over :mod:`acquisition.devices.console`. Every command takes ``--rig``; on a rig file whose bus is
simulated, each command starts a fresh in-process simulator at the park pose (its servos live
only as long as the command), which checks the rig file and the code paths but keeps no state
between commands. Moves run under the Ctrl-C handler of :mod:`acquisition.session.interrupts`.
"""

from __future__ import annotations

import argparse
import logging
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

from acquisition import api

LOGGERS = ("acquisition.devices",)
"""Loggers whose records the CLI shows on stderr (health-guard pauses)."""


@contextmanager
def operator_output() -> Iterator[None]:
    """Show warnings (e.g. the USB latency timer) and guard notices as ``gonio: …`` lines."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
        print(f"gonio: warning: {message}", file=sys.stderr, flush=True)

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("gonio: %(message)s"))
    loggers = [logging.getLogger(name) for name in LOGGERS]
    saved = [(lg, lg.level, lg.propagate) for lg in loggers]
    for lg in loggers:
        lg.addHandler(handler)
        lg.setLevel(logging.INFO)
        lg.propagate = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.showwarning = show
            yield
    finally:
        for lg, level, propagate in saved:
            lg.removeHandler(handler)
            lg.setLevel(level)
            lg.propagate = propagate


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


def _common(p: argparse.ArgumentParser, rig_required: bool = True) -> None:
    from acquisition.cli.capture import add_sim_fault_option  # capture imports this module

    p.add_argument("--rig", required=rig_required, help="rig file (TOML)")
    add_sim_fault_option(p)
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated fault injection")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("status", help="table of every axis: position, goal, temperature, errors")
    _common(p)
    p.set_defaults(func=run_status)

    p = sub.add_parser("scan", help="find servos on the rig's ports (or --port) over baud rates")
    _common(p, rig_required=False)
    p.add_argument("--port", help="scan this port instead of the rig's buses")
    p.add_argument("--bauds", type=int, nargs="+", default=None,
                   metavar="BAUD", help="baud rates to try (default: the common X-series rates)")
    p.add_argument("--ids", type=_ids, default=None,
                   help="IDs to look for, e.g. 1-8 (default: all, by broadcast ping)")
    p.set_defaults(func=run_scan)

    p = sub.add_parser("jog", help="move one axis by DEG degrees (the others hold)")
    _common(p)
    p.add_argument("axis")
    p.add_argument("deg", type=float, help="relative move (degrees; negative allowed)")
    p.set_defaults(func=run_jog)

    p = sub.add_parser("move", help="move to a pose (θi, θr, Δφ in degrees)")
    _common(p)
    p.add_argument("--theta-i", type=float, required=True)
    p.add_argument("--theta-r", type=float, required=True)
    p.add_argument("--delta-phi", type=float, required=True)
    p.set_defaults(func=run_move)

    p = sub.add_parser("home", help="move axes to 0° (their zero_tick); all if none named")
    _common(p)
    p.add_argument("axes", nargs="*", metavar="AXIS")
    p.set_defaults(func=run_home)

    p = sub.add_parser("park", help="move to the park pose (the white-reference pose)")
    _common(p)
    p.set_defaults(func=run_park)

    p = sub.add_parser("torque", help="switch servo torque on or off")
    _common(p)
    p.add_argument("state", choices=("on", "off"))
    p.add_argument("axes", nargs="*", metavar="AXIS", help="axes (default: all)")
    p.set_defaults(func=run_torque)

    p = sub.add_parser("reboot", help="reboot an axis' servo to clear a hardware error")
    _common(p)
    p.add_argument("axis")
    p.set_defaults(func=run_reboot)


@contextmanager
def _console(args: argparse.Namespace) -> Iterator[api.Console]:
    with operator_output(), api.sigint_stops_motion(), api.open_console(
            args.rig, sim_faults=args.sim_fault, seed=args.seed) as con:
        yield con


def _print_joints(joints: dict[str, float]) -> None:
    print("  ".join(f"{name} {deg:.2f}°" for name, deg in joints.items()) + "  (read back)")


def run_status(args: argparse.Namespace) -> int:
    with _console(args) as con:
        rows = con.status()
    print(api.format_status(rows))
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
    print(api.format_scan(results))
    return 0 if any(r.found for r in results) else 1


def run_jog(args: argparse.Namespace) -> int:
    with _console(args) as con:
        _print_joints(con.jog(args.axis, args.deg))
    return 0


def run_move(args: argparse.Namespace) -> int:
    with _console(args) as con:
        _print_joints(con.move_pose(args.theta_i, args.theta_r, args.delta_phi))
    return 0


def run_home(args: argparse.Namespace) -> int:
    with _console(args) as con:
        _print_joints(con.home(args.axes or None))
    return 0


def run_park(args: argparse.Namespace) -> int:
    with _console(args) as con:
        _print_joints(con.park())
    return 0


def run_torque(args: argparse.Namespace) -> int:
    with _console(args) as con:
        con.set_torque(args.state == "on", args.axes or None)
        names = args.axes or con.axis_names
    print(f"torque {args.state}: {', '.join(names)}")
    return 0


def run_reboot(args: argparse.Namespace) -> int:
    with _console(args) as con:
        row = con.reboot(args.axis)
    print(f"rebooted axis '{row.axis}' (servo {row.servo_id}): no hardware error, torque off; "
          f"`gonio torque on` before moving")
    return 0
