"""The ``gonio`` command line: a thin layer over the Python API.

Each command group lives in its own module exposing ``register(subparsers)``, which adds its
parser(s) with ``set_defaults(func=run)``; ``run(args) -> int`` returns the exit code. Errors
derived from :class:`drivers.errors.GonioError` are printed as one line, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from acquisition import api

COMMAND_MODULES: tuple[str, ...] = (
    "acquisition.cli.capture",
    "acquisition.cli.plan",
    "acquisition.cli.demo",
    "acquisition.cli.sim",
    "acquisition.cli.info",
    "acquisition.cli.export",
    "acquisition.cli.console",
    "acquisition.cli.inspect",
    "acquisition.cli.calibrate",
    "acquisition.cli.lightstage",
)
"""Modules that register sub-commands, in the order ``gonio --help`` lists them."""


def build_parser() -> argparse.ArgumentParser:
    """The full ``gonio`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="gonio",
        description="Acquisition control for gonioreflectometers and light stages.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gonio`` console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except api.GonioError as exc:
        print(f"gonio: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("gonio: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
