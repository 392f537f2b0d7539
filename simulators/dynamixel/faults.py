"""Fault specs for the simulated servo bus, parsed from the same strings on the CLI and in Python.

Syntax (one spec per string; ``--fault`` may be repeated):

``drop=P``                 each status packet is not sent with probability P (0–1)
``corrupt=P``              each status packet goes out with a wrong CRC with probability P
``delay=MS``               each status packet is sent MS milliseconds late (host time)
``drop=P,corrupt=Q``       several of the above in one string
``drop:id=N,p=P``          the same, for servo N only (likewise ``corrupt:id=N,p=P``,
                           ``delay:id=N,ms=MS``)
``overload:id=N,after=S``  servo N trips on overload S seconds of simulated time after the bus
                           starts (at the first moment its torque is on): bit 5 of hardware
                           error status, torque off
``overheat:id=N[,after=S][,heat=C]``
                           from S s on, servo N heats up by C °C more (default 60) while its
                           torque is on; past its Temperature Limit it trips (bit 2, torque off)
``voltage:id=N,volts=V[,after=S]``
                           servo N's supply reads V volts from S s on (outside the voltage
                           limits: bit 0, Alert, torque stays on)
``obstruction:id=N,min=T|max=T``
                           servo N's shaft is blocked below/above T ticks (encoder frame): it
                           stalls there, then trips on overload

Randomness comes from one ``random.Random(seed)`` per bus, so a seeded run is repeatable.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from drivers.errors import ConfigError

_SYNTAX = (
    "use drop=P, corrupt=P, delay=MS, overload:id=N,after=S, overheat:id=N, "
    "voltage:id=N,volts=V or obstruction:id=N,min=T"
)

_WIRE = {"drop": "p", "corrupt": "p", "delay": "ms"}
_NAMED = {
    "drop": ({"id", "p"}, {"id", "p"}),
    "corrupt": ({"id", "p"}, {"id", "p"}),
    "delay": ({"id", "ms"}, {"id", "ms"}),
    "overload": ({"id"}, {"id", "after"}),
    "overheat": ({"id"}, {"id", "after", "heat"}),
    "voltage": ({"id", "volts"}, {"id", "volts", "after"}),
    "obstruction": ({"id"}, {"id", "min", "max"}),
}


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` and its numeric parameters (``id`` is None for all servos)."""

    kind: str
    servo_id: int | None = None
    params: dict[str, float] = field(default_factory=dict)

    def __str__(self) -> str:
        parts = ([f"id={self.servo_id}"] if self.servo_id is not None else []) + [
            f"{k}={v:g}" for k, v in self.params.items()
        ]
        return f"{self.kind}:{','.join(parts)}"


def _number(spec: str, key: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(
            f"fault spec {spec!r}: {key}={text!r} is not a number; {_SYNTAX}"
        ) from None


def _pairs(spec: str, body: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for part in body.split(","):
        key, sep, value = part.strip().partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"fault spec {spec!r}: {part!r} is not key=value; {_SYNTAX}")
        out[key.strip()] = _number(spec, key.strip(), value.strip())
    return out


def _check(spec: str, fault: Fault) -> Fault:
    p = fault.params
    if "p" in p and not 0.0 <= p["p"] <= 1.0:
        raise ConfigError(f"fault spec {spec!r}: probability must be within 0..1")
    for key in ("ms", "after"):
        if p.get(key, 0.0) < 0:
            raise ConfigError(f"fault spec {spec!r}: {key} must be >= 0")
    if fault.servo_id is not None and not 0 <= fault.servo_id <= 252:
        raise ConfigError(f"fault spec {spec!r}: id must be within 0..252")
    if fault.kind == "obstruction" and not ({"min", "max"} & p.keys()):
        raise ConfigError(f"fault spec {spec!r}: give min=T and/or max=T (ticks)")
    return fault


def parse_fault(spec: str) -> list[Fault]:
    """Parse one spec string into one or more :class:`Fault` (``drop=P,corrupt=Q`` gives two).

    Raises
    ------
    ConfigError
        The string does not follow the syntax above (the message shows it).
    """
    text = spec.strip()
    if not text:
        raise ConfigError(f"empty fault spec; {_SYNTAX}")
    kind, colon, body = text.partition(":")
    kind = kind.strip().lower()
    if colon:
        if kind not in _NAMED:
            raise ConfigError(f"fault spec {spec!r}: unknown fault {kind!r}; {_SYNTAX}")
        params = _pairs(spec, body)
        required, allowed = _NAMED[kind]
        missing, extra = required - params.keys(), params.keys() - allowed
        if missing or extra:
            what = f"missing {sorted(missing)}" if missing else f"unknown {sorted(extra)}"
            raise ConfigError(f"fault spec {spec!r}: {what}; {_SYNTAX}")
        servo_id = params.pop("id")
        if servo_id != int(servo_id):
            raise ConfigError(f"fault spec {spec!r}: id must be an integer")
        return [_check(spec, Fault(kind, int(servo_id), params))]
    faults = []
    for key, value in _pairs(spec, text).items():
        if key not in _WIRE:
            raise ConfigError(f"fault spec {spec!r}: unknown fault {key!r}; {_SYNTAX}")
        faults.append(_check(spec, Fault(key, None, {_WIRE[key]: value})))
    return faults


def parse_faults(specs: Iterable[str | Fault]) -> list[Fault]:
    """Parse every spec (strings or ready :class:`Fault` objects) into one flat list."""
    out: list[Fault] = []
    for spec in specs:
        out.extend([spec] if isinstance(spec, Fault) else parse_fault(spec))
    return out


@dataclass
class WireFaults:
    """Per-servo wire faults: drop / corrupt probability and extra delay (s)."""

    drop: float = 0.0
    corrupt: float = 0.0
    delay_s: float = 0.0


def wire_faults_for(faults: Iterable[Fault], servo_id: int) -> WireFaults:
    """Combine the wire faults that apply to ``servo_id`` (per-servo specs override global)."""
    wf = WireFaults()
    ordered = sorted(faults, key=lambda f: f.servo_id is not None)  # global first
    for f in ordered:
        if f.kind not in _WIRE or f.servo_id not in (None, servo_id):
            continue
        if f.kind == "drop":
            wf.drop = f.params["p"]
        elif f.kind == "corrupt":
            wf.corrupt = f.params["p"]
        else:
            wf.delay_s = f.params["ms"] / 1000.0
    return wf
