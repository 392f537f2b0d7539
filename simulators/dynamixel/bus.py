"""A simulated Dynamixel bus behind a real pseudo-terminal.

``SimServoBus(ids).start()`` returns a path such as ``/dev/pts/7`` that any client (the
unmodified ``dynamixel_sdk``, a terminal program) opens like a USB adapter. One thread runs a
``select`` loop on the pty master and a wake-up pipe: it parses instruction packets, lets the
:class:`~simulators.dynamixel.responder.Responder` execute them, and writes the status packets
after each servo's Return Delay Time (plus injected delay), in order. ``stop()`` writes to the
wake-up pipe, so shutting down costs microseconds, not a polling timeout.

A new instruction cancels replies still waiting to be sent (the master has moved on), so a reply
delayed past the client's timeout never lands in the next transaction.

Solid parts (optional): given a :class:`~simulators.rig_solids.SolidRig`, the bus builds a
:class:`~simulators.dynamixel.world.SolidWorld` over its servos, so arms that touch stall and
trip on overload; :meth:`SimServoBus.sim_collisions` lists the contacts. Without it the bus is
bare: servos that never meet anything. :func:`drain_collisions` hands over every contact any
simulated bus of the process saw since it was last called (a bus steps its world up to the
present when it stops, and live ones are stepped by the call), for a referee that must see
every bus, whoever started it. Buses of one rig that share a world are built with one
``lock`` and attached with :meth:`SimServoBus.sim_attach_world`
(:mod:`simulators.dynamixel.rig` does that).

Faults: the specs of :mod:`simulators.dynamixel.faults` on status and instruction packets, and
scripted one-shot losses (:meth:`SimServoBus.sim_drop_next`) for deterministic tests. The bus
reports through return values, counters (``stats``, ``instructions``, ``wire_stats``) and
:mod:`logging`, never by printing; :mod:`simulators.dynamixel.serve` runs it in the foreground.

Wire time (``wire_time``): charged by default (``"auto"``: ``"clock"`` on a clock that does not
follow host time, else ``"host"``), as a real bus takes it; ``False`` turns it off (a test that
measures only the pty's overhead). ``"host"`` (or ``True``) delays each
reply in host time by the instruction's and the reply's bytes on the wire, for clients on a
real-time or scaled clock. ``"clock"`` charges them to the shared simulated clock instead, for
a discrete-event :class:`~simulators.clock.SteppedClock`: every instruction advances the clock
by its bytes at the bus baud rate *before* the servos act on it (sync writes, which get no
reply, cost their time too, as on a real half-duplex bus), and every status reply by its
servo's Return Delay Time plus its bytes (at the servo's baud rate) before it is written to
the pty. Either way a byte costs 10 bits (start, 8 data, stop).

By default the servos answer whatever baud rate the client sets on the pty (the SDK's example
programs use other rates than a rig's); ``strict_baud=True`` makes a servo deaf unless the
client's termios speed equals the servo's Baud Rate register, like a real bus.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import termios
import threading
import time
import tty
import weakref
from collections import Counter, deque
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

from drivers.errors import ConfigError
from simulators.clock import SimClock
from simulators.dynamixel import control_table as ct
from simulators.dynamixel.faults import Fault, WireFaults, parse_faults, wire_faults_for
from simulators.dynamixel.protocol import Instruction, Packet, PacketParser
from simulators.dynamixel.responder import Responder
from simulators.dynamixel.servo import SimServo
from simulators.dynamixel.world import DEFAULT_TICK_S, Collision, SolidWorld, take_recorded
from simulators.rig_solids import SolidRig

#: A partial packet older than this (host s) is discarded when new bytes arrive.
_PARTIAL_TIMEOUT_S = 0.1

_TERMIOS_SPEEDS = {
    getattr(termios, f"B{rate}"): rate
    for rate in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                 1000000, 1152000, 2000000, 2500000, 3000000, 3500000, 4000000)
    if hasattr(termios, f"B{rate}")
}
_BAUD_INDEX = {rate: index for index, rate in ct.BAUD_RATES.items()}

#: Bits a byte takes on the wire (start bit, 8 data bits, stop bit).
BITS_PER_BYTE = 10

WireTime = Literal["host", "clock"]
"""Where wire time is charged: replies delayed in host time, or the simulated clock advanced."""

#: Bytes of a Protocol 2.0 packet besides its parameters (header 4, ID, length 2, instr., CRC 2).
_PACKET_OVERHEAD = 10


@dataclass
class _ScriptedLoss:
    """Lose the next ``count`` instructions named in ``names`` (None: any) to one servo."""

    servo_id: int
    names: frozenset[str] | None
    count: int
    corrupt: bool


_LIVE: weakref.WeakSet[SimServoBus] = weakref.WeakSet()
"""Started buses not stopped yet (their worlds are stepped to the present by
:func:`drain_collisions`)."""


def drain_collisions() -> list[Collision]:
    """Every contact of simulated arms in this process since the last call, oldest first per
    world: the buses still running step their worlds to their clocks' present first, so a
    contact under way is found now, not in whatever runs next."""
    for bus in list(_LIVE):
        bus.sim_collisions()
    return take_recorded()


def _wire_time_mode(wire_time: bool | str | None, clock: object = None) -> WireTime | None:
    if wire_time == "auto":
        return "host" if getattr(clock, "follows_host", True) else "clock"
    if wire_time is None or wire_time is False:
        return None
    if wire_time is True:
        return "host"
    if wire_time in ("host", "clock"):
        return wire_time  # type: ignore[return-value]
    raise ConfigError(f"wire_time must be 'auto', False, True, 'host' or 'clock', got {wire_time!r}")


class SimServoBus:
    """Simulated X-series servos on one pty.

    Parameters
    ----------
    ids:
        Servo IDs (1–252; 0 is allowed too), each an XM430-W350 at factory defaults.
    baud:
        Baud rate set in every servo's Baud Rate register (57600, 115200, 1M, 2M, 3M, 4M, ...).
    clock:
        Simulated clock (shared by a rig); a real-time one if None.
    faults:
        Fault specs (strings or :class:`~simulators.dynamixel.faults.Fault`), see
        :mod:`simulators.dynamixel.faults`.
    seed:
        Seed of the fault RNG.
    strict_baud:
        Servos ignore packets when the client's pty speed differs from their baud rate.
    positions:
        Initial shaft position (ticks) per ID; 2048 (centre) otherwise.
    wire_time:
        Charge packets their time on the wire (10 bits per byte): ``"host"`` (or ``True``)
        delays each reply in host time by the instruction's and its own bytes; ``"clock"``
        advances ``clock`` by each instruction's bytes at ``baud`` and each reply's Return
        Delay Time plus bytes (meant for a :class:`~simulators.clock.SteppedClock`; replies
        are then not delayed for it in host time). ``"auto"`` (default): ``"clock"`` when
        ``clock`` does not follow host time, else ``"host"``. ``False``: off (the pty alone).
    strict_fault_ids:
        Refuse fault specs naming an ID that is not on this bus. Off by default, so that a rig
        with several buses can hand the same spec list to each; check the IDs against the
        whole rig instead.
    solids:
        The rig's solid parts; every joint that moves an arm must be driven by a servo of this
        bus (its ``servo_id``). None: a bare bus.
    stall_trip_s:
        Simulated seconds a servo pushes against an obstruction or a contact before it trips on
        overload (the X-series takes about a second).
    physics_tick_s:
        Physics tick of the solid world (simulated s).
    lock:
        Lock shared with other buses of the same solid world (one is made if None).

    Attributes
    ----------
    servos:
        ``{id: SimServo}`` keyed by the ID each servo was created with.
    stats:
        Counters: ``packets`` received, ``replies`` sent, ``dropped``, ``corrupted`` (status
        packets), ``instructions_dropped``, ``instructions_corrupted`` (per addressed servo),
        ``cancelled`` (replies pre-empted by a newer instruction), ``overflow``.
    instructions:
        Instructions received, by name (``"SYNC_WRITE"``, ``"READ"``, ...).
    wire_stats:
        ``{id: Counter}`` of injected faults per servo, keyed by ``(direction, fault,
        instruction)``, e.g. ``("instruction", "dropped", "SYNC_WRITE")`` or
        ``("status", "corrupted", "SYNC_READ")``.
    world:
        The solid world, or None on a bare bus.
    """

    def __init__(
        self,
        ids: Iterable[int],
        *,
        baud: int = 57600,
        clock: SimClock | None = None,
        faults: Iterable[str | Fault] = (),
        seed: int = 0,
        strict_baud: bool = False,
        positions: Mapping[int, float] | None = None,
        wire_time: bool | WireTime | Literal["auto"] = "auto",
        strict_fault_ids: bool = False,
        solids: SolidRig | None = None,
        stall_trip_s: float = 1.0,
        physics_tick_s: float = DEFAULT_TICK_S,
        lock: threading.RLock | None = None,
    ) -> None:
        id_list = [int(i) for i in ids]
        if not id_list:
            raise ConfigError("a simulated servo bus needs at least one servo ID")
        bad = [i for i in id_list if not 0 <= i <= 252]
        if bad:
            raise ConfigError(f"servo IDs must be within 1..252, got {bad}")
        if len(set(id_list)) != len(id_list):
            raise ConfigError(f"servo IDs must be unique, got {id_list}")
        if baud not in _BAUD_INDEX:
            raise ConfigError(
                f"baud rate {baud} is not one an X-series servo supports; "
                f"use one of {sorted(_BAUD_INDEX)}"
            )
        self.baud = baud
        self.clock = clock if clock is not None else SimClock()
        self.faults = parse_faults(faults)
        unknown = sorted({f.servo_id for f in self.faults if f.servo_id is not None} - set(id_list))
        if unknown and strict_fault_ids:
            raise ConfigError(f"fault specs name servo IDs {unknown} that are not on the bus "
                              f"{sorted(id_list)}")
        self.strict_baud = strict_baud
        self.wire_time: WireTime | None = _wire_time_mode(wire_time, self.clock)
        """``"host"``, ``"clock"`` or None (off), see the ``wire_time`` parameter."""
        if stall_trip_s < 0:
            raise ConfigError(f"stall_trip_s must be >= 0 s, got {stall_trip_s}")
        self._lock = lock if lock is not None else threading.RLock()
        self._rng = random.Random(seed)
        positions = positions or {}
        self.servos: dict[int, SimServo] = {
            i: SimServo(
                i, self.clock, baud_index=_BAUD_INDEX[baud],
                position_ticks=positions.get(i, 2048.0),
                stall_trip_s=stall_trip_s,
                faults=tuple(f for f in self.faults if f.servo_id == i and f.kind not in
                             ("drop", "corrupt", "delay")),
                lock=self._lock,
            )
            for i in id_list
        }
        self._id_of = {servo: i for i, servo in self.servos.items()}
        self._wire: dict[SimServo, WireFaults] = {
            servo: wire_faults_for(self.faults, i) for i, servo in self.servos.items()}
        self._responder = Responder(list(self.servos.values()),
                                    self._hears if strict_baud else None)
        self.stats = dict(packets=0, replies=0, dropped=0, corrupted=0, instructions_dropped=0,
                          instructions_corrupted=0, cancelled=0, overflow=0)
        self.instructions: Counter[str] = Counter()
        self.wire_stats: dict[int, Counter[tuple[str, str, str]]] = {
            i: Counter() for i in self.servos}
        self._scripted: list[_ScriptedLoss] = []
        self.world: SolidWorld | None = None
        if solids is not None and solids.arms:
            by_id = {a.servo_id: name for name, a in solids.axes.items()}
            joints = {by_id[i]: s for i, s in self.servos.items() if i in by_id}
            missing = [j for js in solids.arm_axes.values() for j in js if j not in joints]
            if missing:
                raise ConfigError(f"solid parts need the servos of axes {missing} on this bus "
                                  f"(IDs {sorted(self.servos)})")
            self.world = SolidWorld(solids, joints, tick_s=physics_tick_s)
        self._master = self._slave = self._wake_r = self._wake_w = -1
        self._thread: threading.Thread | None = None
        self._port: str | None = None
        self._client_baud: int | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> str:
        """The pty slave path clients open (only while started)."""
        if self._port is None:
            raise RuntimeError("the simulated servo bus is not started")
        return self._port

    def start(self) -> str:
        """Open the pty, start the responder thread, return the slave path."""
        if self._thread is not None:
            return self.port
        self._master, self._slave = os.openpty()
        # Raw mode: no echo, no CR/LF translation, 8 bits (clients set it again; harmless).
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self._wake_r, self._wake_w = os.pipe()
        self._port = os.ttyname(self._slave)
        self._thread = threading.Thread(
            target=self._run, name=f"sim-servo-bus {self._port}", daemon=True)
        self._thread.start()
        _LIVE.add(self)
        return self._port

    def stop(self) -> None:
        """Stop the thread and close the pty (the slave path disappears)."""
        if self._thread is None:
            return
        _LIVE.discard(self)
        self.sim_collisions()  # the world up to now: contacts are found while their run lasts
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join()
        self._thread = None
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1
        self._port = None

    def __enter__(self) -> SimServoBus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ sim-only API
    def sim_attach_world(self, world: SolidWorld) -> None:
        """Make ``world`` (built over servos of this and other buses sharing this bus's lock)
        this bus's solid world, for :meth:`sim_collisions`."""
        self.world = world

    def sim_collisions(self) -> list[Collision]:
        """Every contact of the arms so far (oldest first); empty on a bare bus."""
        with self._lock:
            return [] if self.world is None else self.world.collisions_at(self.clock.now())

    def sim_drop_next(self, servo_id: int, instructions: Collection[str] | None = ("SYNC_WRITE",),
                      count: int = 1, *, corrupt: bool = False) -> None:
        """Make servo ``servo_id`` miss its next ``count`` instructions named in
        ``instructions`` (``"SYNC_WRITE"``, ``"WRITE"``, ...; None: any), as if they were
        dropped on the wire (or, with ``corrupt``, arrived with a bad CRC). Deterministic,
        unlike the probabilistic fault specs; counted in ``wire_stats`` like them."""
        if servo_id not in self.servos:
            raise ConfigError(f"servo {servo_id} is not on this bus ({sorted(self.servos)})")
        names = None if instructions is None else frozenset(n.upper() for n in instructions)
        with self._lock:
            self._scripted.append(_ScriptedLoss(servo_id, names, int(count), corrupt))

    def _instruction_fates(self, pkt: Packet, name: str) -> tuple[set[SimServo], set[SimServo]]:
        """(deaf, garbled): the addressed servos that lose this instruction."""
        deaf: set[SimServo] = set()
        garbled: set[SimServo] = set()
        for servo in self._responder.addressed(pkt):
            sid = self._id_of[servo]
            wf = self._wire[servo]
            fate = None
            for loss in self._scripted:
                if loss.servo_id == sid and loss.count > 0 and (
                        loss.names is None or name in loss.names):
                    loss.count -= 1
                    fate = "corrupted" if loss.corrupt else "dropped"
                    break
            if fate is None and wf.instruction_drop and self._rng.random() < wf.instruction_drop:
                fate = "dropped"
            if fate is None and wf.instruction_corrupt and (
                    self._rng.random() < wf.instruction_corrupt):
                fate = "corrupted"
            if fate is None:
                continue
            (deaf if fate == "dropped" else garbled).add(servo)
            self.stats[f"instructions_{fate}"] += 1
            self.wire_stats[sid]["instruction", fate, name] += 1
        self._scripted = [loss for loss in self._scripted if loss.count > 0]
        return deaf, garbled

    # ------------------------------------------------------------------ loop
    def _hears(self, servo: SimServo) -> bool:
        return self._client_baud is None or self._client_baud == servo.baud_rate

    def _read_client_baud(self) -> int | None:
        try:
            return _TERMIOS_SPEEDS.get(termios.tcgetattr(self._slave)[5])
        except termios.error:
            return None

    def _run(self) -> None:
        parser = PacketParser()
        pending: deque[tuple[float, bytes]] = deque()
        partial_since = 0.0
        master, wake = self._master, self._wake_r
        while True:
            timeout = max(0.0, pending[0][0] - time.monotonic()) if pending else None
            readable, _, _ = select.select([master, wake], [], [], timeout)
            if wake in readable:
                return
            if master in readable:
                try:
                    data = os.read(master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:  # no slave open at all; cannot happen while we hold ours
                    return
                now = time.monotonic()
                if data:
                    if parser.pending and now - partial_since > _PARTIAL_TIMEOUT_S:
                        parser.clear()
                    for pkt in parser.feed(data):
                        self.stats["packets"] += 1
                        if pending:
                            self.stats["cancelled"] += len(pending)
                            pending.clear()
                        self._schedule(pkt, now, pending)
                    if not parser.pending:
                        partial_since = 0.0
                    elif not partial_since:
                        partial_since = now
            self._flush(pending)

    def _schedule(self, pkt: Packet, now: float, pending: deque[tuple[float, bytes]]) -> None:
        try:
            name = Instruction(pkt.instruction).name
        except ValueError:
            name = f"0x{pkt.instruction:02X}"
        self.instructions[name if pkt.crc_ok else "BAD_CRC"] += 1
        host_wire, clock_wire = self.wire_time == "host", self.wire_time == "clock"
        if clock_wire:  # the servos act once the whole instruction has arrived
            self.clock.advance((_PACKET_OVERHEAD + len(pkt.params)) * BITS_PER_BYTE / self.baud)
        spent_s = 0.0  # clock time the replies take (clock wire time)
        with self._lock:
            if self.strict_baud:
                self._client_baud = self._read_client_baud()
            deaf, garbled = self._instruction_fates(pkt, name) if pkt.crc_ok else ((), ())
            replies = self._responder.handle(pkt, deaf, garbled)
            due = now
            if host_wire and replies:
                due += (_PACKET_OVERHEAD + len(pkt.params)) * BITS_PER_BYTE / replies[0][0].baud_rate
            for servo, raw in replies:
                wf = self._wire[servo]
                drop = self._rng.random() < wf.drop
                corrupt = self._rng.random() < wf.corrupt
                due += servo.return_delay_s + wf.delay_s
                if host_wire:
                    due += len(raw) * BITS_PER_BYTE / servo.baud_rate
                if drop:
                    self.stats["dropped"] += 1
                    self.wire_stats[self._id_of[servo]]["status", "dropped", name] += 1
                    continue
                if corrupt:
                    self.stats["corrupted"] += 1
                    self.wire_stats[self._id_of[servo]]["status", "corrupted", name] += 1
                    raw = raw[:-1] + bytes([raw[-1] ^ 0xFF])
                if clock_wire:
                    spent_s += servo.return_delay_s + len(raw) * BITS_PER_BYTE / servo.baud_rate
                pending.append((due, raw))
        if spent_s:
            self.clock.advance(spent_s)

    def _flush(self, pending: deque[tuple[float, bytes]]) -> None:
        now = time.monotonic()
        out = bytearray()
        while pending and pending[0][0] <= now:
            out += pending.popleft()[1]
            self.stats["replies"] += 1
        while out:
            try:
                n = os.write(self._master, out)
            except BlockingIOError:
                self.stats["overflow"] += 1  # nobody reads the port: the bytes are lost
                return
            del out[:n]

