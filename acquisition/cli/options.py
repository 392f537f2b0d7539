"""Options every command spells the same way, and the one way a command reports."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any


def add_out(p: argparse.ArgumentParser, help: str, *, required: bool = False,
            aliases: Iterable[str] = ()) -> None:
    """``-o/--out PATH`` (older spellings in ``aliases`` keep working)."""
    p.add_argument("-o", "--out", *aliases, dest="out", metavar="PATH", required=required,
                   help=help)


def add_json(p: argparse.ArgumentParser) -> None:
    """``--json``: one JSON object on stdout instead of the text report."""
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def add_seed(p: argparse.ArgumentParser) -> None:
    """``--seed N``: the simulated devices' noise seed."""
    p.add_argument("--seed", type=int, default=0,
                   help="noise seed of the simulated devices (default 0)")


def add_sim_fault(p: argparse.ArgumentParser, *aliases: str) -> None:
    """``--sim-fault SPEC`` (repeatable): a fault for the simulated servo bus."""
    p.add_argument("--sim-fault", *aliases, dest="sim_fault", action="append", default=[],
                   metavar="SPEC",
                   help="inject a fault into the simulated servo bus (e.g. drop=0.05, "
                        "corrupt=0.05, delay=MS, overload:id=2,after=20); repeatable")


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON types (paths as strings, dataclasses as objects, NaN as null)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set)):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return jsonable(value.tolist())
    return value


def report(args: argparse.Namespace, payload: Mapping[str, Any], lines: Iterable[str]) -> None:
    """Print ``payload`` as one JSON object with ``--json``, else the text ``lines``."""
    if getattr(args, "json", False):
        print(json.dumps(jsonable(payload)))
    else:
        for line in lines:
            print(line)
