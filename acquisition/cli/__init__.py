"""The ``gonio`` command line: a thin layer over :mod:`acquisition.api`.

Each command group lives in its own module exposing ``COMMANDS`` (command name → one-line
help) and ``register(subparsers)``, which adds the full parser(s) with
``set_defaults(func=run)``; ``run(args) -> int`` returns the exit code. Only the command being
run is registered in full, so ``gonio --help`` imports nothing but these modules. Errors
derived from :class:`drivers.errors.GonioError` are printed as one line, never a traceback (an
``OSError`` that escaped one too, as a last resort).

Grammar shared by every command: outputs are ``-o/--out``; ``--json`` prints one JSON object
on stdout instead of the text report; ``--seed`` is the simulated devices' noise seed;
``--sim-fault SPEC`` injects faults into simulated devices.

May import: ``acquisition.api`` (and its own modules), nothing else of gonio's.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

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
    "acquisition.cli.analyze",
)
"""Modules that register sub-commands, in the order ``gonio --help`` lists them."""


def gonio_version() -> str:
    """The installed distribution's version (``gonio --version``)."""
    try:
        return version("gonio")
    except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
        return "unknown"


def build_parser(command: str | None = None, *, full: bool = True) -> argparse.ArgumentParser:
    """The ``gonio`` argument parser.

    ``full``: every command's complete parser (tests, completion). Otherwise only ``command``'s
    module registers its parsers in full and the others are listed by name and help.
    """
    parser = argparse.ArgumentParser(
        prog="gonio",
        description="Acquisition control for gonioreflectometers and light stages.",
    )
    parser.add_argument("--version", action="version", version=f"gonio {gonio_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        module = importlib.import_module(name)
        if full or command in module.COMMANDS:
            module.register(sub)
        else:
            for cmd, text in module.COMMANDS.items():
                sub.add_parser(cmd, help=text)
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The sub-command named in ``argv`` (the first argument not starting with ``-``)."""
    return next((a for a in argv if not a.startswith("-")), None)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``gonio`` console script; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(_command_in(argv), full=False)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except api.GonioError as exc:
        print(f"gonio: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # `gonio … | head`: the reader left; say nothing more
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:  # the last resort: a disk error nothing named is still one line
        print(f"gonio: error: {api.os_error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("gonio: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
