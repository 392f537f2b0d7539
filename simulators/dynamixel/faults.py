"""Fault specs for the simulated servo bus, parsed from the same strings on the CLI and in Python.

Syntax (one spec per string; ``--fault`` may be repeated):

``drop=P``                 each status packet is not sent with probability P (0–1)
``corrupt=P``              each status packet goes out with a wrong CRC with probability P
``delay=MS``               each status packet is sent MS milliseconds late (host time)
``drop=P,corrupt=Q``       several of the above in one string
``drop=P,corrupt=Q,dir=D`` ``drop``/``corrupt`` in direction D: ``status`` (servo → host, the
                           default, so every older spec keeps its meaning), ``instruction``
                           (host → servo) or ``both``; e.g. a noisy cable is
                           ``drop=0.05,corrupt=0.05,dir=both``
``drop:id=N,p=P[,dir=D]``  the same, for servo N only (likewise ``corrupt:id=N,p=P[,dir=D]``,
                           ``delay:id=N,ms=MS``)

Instruction faults are drawn per servo that the packet addresses (the unicast ID, the IDs of a
SYNC/BULK instruction, every servo for other broadcasts), so one servo may miss a SYNC_WRITE
that the others act on. A dropped instruction is never heard: no action, no reply (a read then
times out). A corrupted one is heard with a wrong CRC and discarded: a unicast packet is
answered with the CRC error (error number 3, as the X-series e-manual states), a broadcast one
(SYNC_WRITE, SYNC_READ, ...) is ignored by that servo. ``delay`` applies to status packets only.
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

Randomness comes from one ``random.Random(seed)`` per bus, so a seeded run is repeatable (an
instruction fault draws from it only when its probability is non-zero, so adding none leaves
the status-packet draws of older seeded runs unchanged).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass, field

from drivers.errors import ConfigError

_SYNTAX = (
    "use drop=P, corrupt=P (add dir=status|instruction|both), delay=MS, "
    "overload:id=N,after=S, overheat:id=N, voltage:id=N,volts=V or obstruction:id=N,min=T"
)


class Direction(enum.Flag):
    """Which packets a ``drop``/``corrupt`` fault hits."""

    STATUS = enum.auto()
    """Status packets, servo → host (the default)."""
    INSTRUCTION = enum.auto()
    """Instruction packets, host → servo."""
    BOTH = STATUS | INSTRUCTION

    @property
    def word(self) -> str:
        """The spelling in a fault spec (``status``, ``instruction``, ``both``)."""
        return {Direction.STATUS: "status", Direction.INSTRUCTION: "instruction"}.get(self, "both")


_DIRECTIONS = {"status": Direction.STATUS, "instruction": Direction.INSTRUCTION,
               "both": Direction.BOTH}

_WIRE = {"drop": "p", "corrupt": "p", "delay": "ms"}
_NAMED = {
    "drop": ({"id", "p"}, {"id", "p", "dir"}),
    "corrupt": ({"id", "p"}, {"id", "p", "dir"}),
    "delay": ({"id", "ms"}, {"id", "ms"}),
    "overload": ({"id"}, {"id", "after"}),
    "overheat": ({"id"}, {"id", "after", "heat"}),
    "voltage": ({"id", "volts"}, {"id", "volts", "after"}),
    "obstruction": ({"id"}, {"id", "min", "max"}),
}


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind``, its numeric parameters (``id`` is None for all servos) and, for
    ``drop``/``corrupt``, the packets it hits."""

    kind: str
    servo_id: int | None = None
    params: dict[str, float] = field(default_factory=dict)
    direction: Direction = Direction.STATUS

    def __str__(self) -> str:
        parts = ([f"id={self.servo_id}"] if self.servo_id is not None else []) + [
            f"{k}={v:g}" for k, v in self.params.items()
        ]
        if self.direction != Direction.STATUS:
            parts.append(f"dir={self.direction.word}")
        return f"{self.kind}:{','.join(parts)}"


def _number(spec: str, key: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ConfigError(
            f"fault spec {spec!r}: {key}={text!r} is not a number; {_SYNTAX}"
        ) from None


def _pairs(spec: str, body: str) -> tuple[dict[str, float], Direction | None]:
    """Numeric ``key=value`` pairs, and the ``dir=`` word if there is one."""
    out: dict[str, float] = {}
    direction: Direction | None = None
    for part in body.split(","):
        key, sep, value = part.strip().partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            raise ConfigError(f"fault spec {spec!r}: {part!r} is not key=value; {_SYNTAX}")
        if key == "dir":
            if value.lower() not in _DIRECTIONS:
                raise ConfigError(f"fault spec {spec!r}: dir={value!r} must be status, "
                                  f"instruction or both")
            direction = _DIRECTIONS[value.lower()]
        else:
            out[key] = _number(spec, key, value)
    return out, direction


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
        params, direction = _pairs(spec, body)
        required, allowed = _NAMED[kind]
        given = params.keys() | ({"dir"} if direction is not None else set())
        missing, extra = required - given, given - allowed
        if missing or extra:
            what = f"missing {sorted(missing)}" if missing else f"unknown {sorted(extra)}"
            raise ConfigError(f"fault spec {spec!r}: {what}; {_SYNTAX}")
        servo_id = params.pop("id")
        if servo_id != int(servo_id):
            raise ConfigError(f"fault spec {spec!r}: id must be an integer")
        return [_check(spec, Fault(kind, int(servo_id), params,
                                   direction or Direction.STATUS))]
    faults = []
    pairs, direction = _pairs(spec, text)
    if direction is not None and not {"drop", "corrupt"} & pairs.keys():
        raise ConfigError(f"fault spec {spec!r}: dir= needs drop=P or corrupt=P; {_SYNTAX}")
    for key, value in pairs.items():
        if key not in _WIRE:
            raise ConfigError(f"fault spec {spec!r}: unknown fault {key!r}; {_SYNTAX}")
        hits = direction if key != "delay" and direction is not None else Direction.STATUS
        faults.append(_check(spec, Fault(key, None, {_WIRE[key]: value}, hits)))
    return faults


def parse_faults(specs: Iterable[str | Fault]) -> list[Fault]:
    """Parse every spec (strings or ready :class:`Fault` objects) into one flat list."""
    out: list[Fault] = []
    for spec in specs:
        out.extend([spec] if isinstance(spec, Fault) else parse_fault(spec))
    return out


@dataclass
class WireFaults:
    """Per-servo wire faults: drop / corrupt probability of its status packets and of the
    instruction packets addressed to it, and extra reply delay (s)."""

    drop: float = 0.0
    corrupt: float = 0.0
    delay_s: float = 0.0
    instruction_drop: float = 0.0
    instruction_corrupt: float = 0.0


def wire_faults_for(faults: Iterable[Fault], servo_id: int) -> WireFaults:
    """Combine the wire faults that apply to ``servo_id`` (per-servo specs override global)."""
    wf = WireFaults()
    ordered = sorted(faults, key=lambda f: f.servo_id is not None)  # global first
    for f in ordered:
        if f.kind not in _WIRE or f.servo_id not in (None, servo_id):
            continue
        p = f.params.get("p", 0.0)
        if f.kind == "delay":
            wf.delay_s = f.params["ms"] / 1000.0
        elif f.kind == "drop":
            if Direction.STATUS in f.direction:
                wf.drop = p
            if Direction.INSTRUCTION in f.direction:
                wf.instruction_drop = p
        else:
            if Direction.STATUS in f.direction:
                wf.corrupt = p
            if Direction.INSTRUCTION in f.direction:
                wf.instruction_corrupt = p
    return wf
