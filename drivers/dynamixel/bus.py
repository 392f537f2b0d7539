"""A Dynamixel Protocol 2.0 bus over ``dynamixel_sdk``: open, ping/scan, torque, sync I/O.

:class:`ServoBus` wraps one ``PortHandler`` and serialises every transfer with a lock (the SDK is
not thread-safe). Communication failures (timeout, corrupt packet, busy port) are retried with
exponential backoff and hidden from the caller; a servo that stays silent raises
:class:`~drivers.dynamixel.codes.ServoSilentError` naming the bus, port, servo ID and axis.
Status packets whose Alert bit is set make the bus read Hardware Error Status and raise the
typed :class:`~drivers.dynamixel.codes.ServoHardwareError` subclass.

Link health is counted per servo (:meth:`ServoBus.servo_stats`): requests, retries (an attempt
repeated after a missing, late or corrupt reply) and resends (a goal write sent again because
the read-back goal showed it never arrived: a SYNC_WRITE gets no reply, so only a read-back can
tell; :class:`~drivers.dynamixel.motion.MotionController` does that in its polling read).

Packets are framed (stuffing, CRC) and parsed by the SDK (``txPacket``, ``syncReadTx``,
``rxPacket``), but the bus waits for replies in ``select`` instead of the SDK's busy-polling
loop, which on a loaded machine starves whoever has to answer. Sync reads do not use
``GroupSyncRead.rxPacket``: that stops at the first missing reply and the SDK's ``readRx``
discards the replies of the other servos while looking for it; the bus collects every status
packet by ID and asks again only the servos that did not answer.

Low latency on real hardware
----------------------------
A round trip through a USB adapter costs at least the adapter's latency: FTDI chips (U2D2,
USB2Dynamixel) buffer up to ``latency_timer`` ms (default 16) before passing bytes on. Set it to
1 ms (``echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer``, or a udev rule
``ATTR{device/latency_timer}="1"``); :func:`drivers.dynamixel.latency.latency_warning` checks it.
Also set each servo's Return Delay Time (address 9) to 0 (default 250 = 500 µs per reply) with
:meth:`ServoBus.set_return_delay` while torque is off. The SDK's packet timeout is
``2 × dynamixel_sdk.port_handler.LATENCY_TIMER + 2`` ms (≈ 34 ms); with a 1 ms adapter it could
be lowered, but it is a module global shared by every port, so gonio leaves it alone.
"""

from __future__ import annotations

import contextlib
import fcntl
import select
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace

import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    COMM_TX_FAIL,
    INST_PING,
    INST_READ,
    INST_REBOOT,
    INST_WRITE,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from drivers.dynamixel import codes
from drivers.dynamixel.codes import (
    ALERT_BIT,
    ERRNUM_CRC,
    ServoCommandError,
    ServoSilentError,
    comm_text,
    hardware_error,
    packet_error_text,
)
from drivers.errors import CommunicationError, ConfigError, LimitError

#: Baud rates the SDK's PortHandler accepts.
SDK_BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                  1000000, 1152000, 2000000, 2500000, 3000000, 3500000, 4000000)
#: Rates an X-series servo can be set to, most common first (what ``scan`` tries).
COMMON_BAUD_RATES = (57600, 1000000, 115200, 2000000, 3000000, 4000000, 9600)


class Addr:
    """X-series control-table addresses used by the driver."""

    MODEL_NUMBER = 0
    RETURN_DELAY_TIME = 9
    TORQUE_ENABLE = 64
    HARDWARE_ERROR_STATUS = 70
    PROFILE_ACCELERATION = 108
    PROFILE_VELOCITY = 112
    GOAL_POSITION = 116
    MOVING = 122
    PRESENT_VELOCITY = 128
    PRESENT_POSITION = 132
    PRESENT_INPUT_VOLTAGE = 144
    PRESENT_TEMPERATURE = 146
    SHUTDOWN = 63


@dataclass(frozen=True)
class ServoStatus:
    """One servo's state for an operator's table (ticks, °C, V)."""

    position: int
    goal: int
    moving: bool
    temperature_c: int
    voltage_v: float
    hardware_error: int
    torque_on: bool


@dataclass(frozen=True)
class MotionSample:
    """What one control cycle reads back: goal and present position (ticks), velocity
    (0.229 rev/min units), moving flag."""

    goal: int
    moving: bool
    velocity: int
    position: int


@dataclass
class ServoLinkStats:
    """Link health of one servo since the bus was made (what ``gonio info`` shows per axis).

    Attributes
    ----------
    requests:
        Instructions addressed to the servo, first attempts only (a sync read or write counts
        once for each servo in it).
    retries:
        Attempts repeated after a missing, late or corrupt reply (or a CRC error the servo
        reported back).
    resends:
        Goal writes sent again because the read-back goal showed they never arrived.
    """

    requests: int = 0
    retries: int = 0
    resends: int = 0

    @property
    def retry_fraction(self) -> float:
        """Retries per request (0 when nothing was asked)."""
        return self.retries / self.requests if self.requests else 0.0

    def __str__(self) -> str:
        return (f"{self.requests} requests, {self.retries} retries "
                f"({100 * self.retry_fraction:.1f} %), {self.resends} resends")


def _le(value: int, size: int) -> list[int]:
    return list((value & ((1 << (8 * size)) - 1)).to_bytes(size, "little"))


def _int(data: bytes, offset: int, size: int, signed: bool = True) -> int:
    return int.from_bytes(data[offset : offset + size], "little", signed=signed)


class ServoBus:
    """One Dynamixel bus on a serial port (or a simulator's pty).

    Parameters
    ----------
    port:
        Device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, a pty).
    baud:
        Bus baud rate (bit/s); one of :data:`SDK_BAUD_RATES`.
    retries:
        Extra attempts per servo after a failed transfer (each after a growing pause). With 8,
        a bus that loses 5 % and garbles 5 % of its packets in each direction (~19 % of round
        trips fail) still fails only ~1 transfer in 4 million; a servo that is really gone
        costs ~0.6 s before :class:`ServoSilentError`.
    backoff_s:
        Pause before the first retry (s); doubles on each further retry.
    name:
        Bus name used in messages (the rig's name for it); the port path if None.
    axis_names:
        ``{servo_id: axis name}`` for messages (also settable with :meth:`label`).
    lock_port:
        Take an exclusive ``flock`` on the port, so two gonio processes cannot share a bus.
    reply_grace_s:
        Host seconds a reply may take beyond the SDK's packet timeout (≈ 34 ms). 0 for real
        servos. An in-process simulator on a discrete-event clock answers in host scheduling
        time, which on a loaded host can pass 34 ms: a late reply taken for a lost one would
        add a retry (and its wire time) to the rig's timeline, so its rig allows more.

    Examples
    --------
    >>> with ServoBus("/dev/ttyUSB0", 57600, name="arms") as bus:  # doctest: +SKIP
    ...     bus.set_torque([1, 2], True)
    ...     bus.write_goals({1: 2048, 2: 3000})
    ...     bus.read_positions([1, 2])
    {1: 2048, 2: 2120}
    """

    def __init__(
        self,
        port: str,
        baud: int = 57600,
        *,
        retries: int = 8,
        backoff_s: float = 0.001,
        name: str | None = None,
        axis_names: Mapping[int, str] | None = None,
        lock_port: bool = True,
        reply_grace_s: float = 0.0,
    ) -> None:
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        if reply_grace_s < 0:
            raise ValueError(f"reply_grace_s must be >= 0, got {reply_grace_s}")
        self.reply_grace_ms = 1000.0 * reply_grace_s
        self.port_name = port
        self.baud = baud
        self.retries = retries
        self.backoff_s = backoff_s
        self.name = name or port
        self.lock_port = lock_port
        self._axis_names: dict[int, str] = dict(axis_names or {})
        self._lock = threading.RLock()
        self._goal_permits = 0  # > 0 while the motion controller writes goals it has guarded
        self._port: PortHandler | None = None
        self._ph = PacketHandler(2.0)
        self.stats = {"transfers": 0, "retries": 0, "resends": 0}
        self._link: dict[int, ServoLinkStats] = {}

    # ------------------------------------------------------------------ open / close
    def open(self) -> ServoBus:
        """Open the port at :attr:`baud`; one-line errors for a bad port or baud rate."""
        with self._lock:
            if self._port is not None:
                return self
            if self.baud not in SDK_BAUD_RATES:
                raise ConfigError(
                    f"bus '{self.name}': baud rate {self.baud} is not supported by "
                    f"dynamixel_sdk; use one of {', '.join(map(str, COMMON_BAUD_RATES))}"
                )
            port = PortHandler(self.port_name)
            port.baudrate = self.baud
            try:
                port.openPort()
            except (serial.SerialException, OSError) as exc:
                reason = getattr(exc, "strerror", None) or str(exc).split(": ")[-1] or str(exc)
                raise CommunicationError(
                    f"cannot open servo port {self.port_name} (bus '{self.name}'): {reason}; "
                    f"check the USB cable and the port in the rig file "
                    f"(ls /dev/serial/by-id/)"
                ) from None
            if self.lock_port:
                try:
                    fcntl.flock(port.ser.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    port.closePort()
                    raise CommunicationError(
                        f"servo port {self.port_name} (bus '{self.name}') is already in use by "
                        f"another gonio process; stop it first"
                    ) from None
            self._port = port
            return self

    def close(self) -> None:
        """Close the port (idempotent)."""
        with self._lock:
            if self._port is not None:
                with contextlib.suppress(Exception):
                    self._port.closePort()
                self._port = None

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def __enter__(self) -> ServoBus:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def label(self, servo_id: int, axis_name: str) -> None:
        """Name the axis driven by ``servo_id`` (used in every message about it)."""
        self._axis_names[servo_id] = axis_name

    def describe(self, servo_id: int) -> str:
        """``"axis 'theta_i' (servo 2 on bus 'arms', /dev/ttyUSB0)"`` or without the axis."""
        if self.name == self.port_name:
            where = f"servo {servo_id} on {self.port_name}"
        else:
            where = f"servo {servo_id} on bus '{self.name}', {self.port_name}"
        axis = self._axis_names.get(servo_id)
        return f"axis '{axis}' ({where})" if axis else where

    # ------------------------------------------------------------------ transfer plumbing
    def _begin(self) -> PortHandler:
        if self._port is None:
            raise CommunicationError(
                f"bus '{self.name}' ({self.port_name}) is not open; open it (use `with "
                f"ServoBus(...)`) before talking to servos"
            )
        # The SDK sets is_using in txPacket and clears it only on its normal paths: after an
        # exception (Ctrl-C) it stays set and every later transfer returns COMM_PORT_BUSY.
        # We hold our own lock, so nobody else is using the port.
        self._port.is_using = False
        self.stats["transfers"] += 1
        return self._port

    def recover(self) -> None:
        """Make the port usable after a failed transfer: clear ``is_using``, flush the input,
        reopen the port if flushing fails."""
        with self._lock:
            port = self._port
            if port is None:
                return
            port.is_using = False
            try:
                port.clearPort()
            except (serial.SerialException, OSError, TypeError):
                with contextlib.suppress(Exception):
                    port.closePort()
                self._port = None
                self.open()

    def _pause(self, attempt: int) -> None:
        self.stats["retries"] += 1
        time.sleep(self.backoff_s * (2 ** (attempt - 1)))
        self.recover()

    def _count(self, ids: Iterable[int], what: str) -> None:
        for i in ids:
            link = self._link.setdefault(i, ServoLinkStats())
            setattr(link, what, getattr(link, what) + 1)

    def servo_stats(self) -> dict[int, ServoLinkStats]:
        """``{servo ID: ServoLinkStats}`` (copies) of every servo the bus has talked to."""
        with self._lock:
            return {i: replace(link) for i, link in sorted(self._link.items())}

    def _silent(self, ids: Iterable[int], result: int, attempts: int) -> ServoSilentError:
        ids = list(ids)
        who = "; ".join(self.describe(i) for i in ids)
        return ServoSilentError(
            f"{who}: no valid answer after {attempts} attempts ({comm_text(result)}); check the "
            f"servo's power and cable, its ID and baud rate ({self.baud}) with `gonio scan`"
        )

    def _refused(self, servo_id: int, error: int, what: str) -> ServoCommandError:
        return ServoCommandError(
            f"{self.describe(servo_id)} refused {what}: {packet_error_text(error)}"
        )

    def _wait_for_reply(self, port: PortHandler) -> None:
        """Block (without the GIL, without burning CPU) until reply bytes arrive or the SDK's
        packet timeout is over; the SDK's own receive loop busy-polls, which on a loaded
        machine starves whoever must answer (an in-process simulator, other processes)."""
        if port.ser.in_waiting:
            return
        remaining_ms = port.packet_timeout - port.getTimeSinceStart()
        if remaining_ms > 0:
            select.select([port.ser.fileno()], [], [], remaining_ms / 1000.0)

    def _exchange_once(self, servo_id: int, instruction: int, params: list[int],
                       reply_size: int) -> tuple[int, bytes, int]:
        """Send one instruction packet; return (SDK result, data, error byte) of its reply."""
        port = self._begin()
        length = len(params) + 3
        packet = [0, 0, 0, 0, servo_id, length & 0xFF, length >> 8, instruction, *params, 0, 0]
        try:
            result = self._ph.txPacket(port, packet)  # stuffing, header and CRC by the SDK
            if result != COMM_SUCCESS:
                return result, b"", 0
            port.setPacketTimeout(reply_size + 11)
            port.packet_timeout += self.reply_grace_ms
            for _ in range(8):
                self._wait_for_reply(port)
                reply, result = self._ph.rxPacket(port, False)
                if result != COMM_SUCCESS:
                    return result, b"", 0
                if reply[4] != servo_id:
                    continue  # someone else's (late) packet
                error = reply[8]
                data = bytes(reply[9 : 9 + reply_size])
                if (error & ~ALERT_BIT) == ERRNUM_CRC:
                    return COMM_RX_CORRUPT, b"", 0  # the servo got a garbled packet: resend
                if not (error & ~ALERT_BIT) and len(data) != reply_size:
                    continue  # a late reply to an older request
                return COMM_SUCCESS, data, error
            return COMM_RX_CORRUPT, b"", 0
        except (serial.SerialException, OSError):
            return COMM_TX_FAIL, b"", 0
        finally:
            port.is_using = False

    def _exchange(self, servo_id: int, instruction: int, params: Sequence[int] = (),
                  reply_size: int = 0, attempts: int | None = None) -> tuple[bytes, int]:
        """One instruction to one servo with bounded retries: (reply data, error byte)."""
        result = COMM_TX_FAIL
        attempts = self.retries + 1 if attempts is None else attempts
        for attempt in range(attempts):
            with self._lock:
                self._count([servo_id], "retries" if attempt else "requests")
                if attempt:
                    self._pause(attempt)
                result, data, error = self._exchange_once(servo_id, instruction, list(params),
                                                          reply_size)
            if result == COMM_SUCCESS:
                return data, error
        raise self._silent([servo_id], result, attempts)

    # ------------------------------------------------------------------ single-servo I/O
    def read(self, servo_id: int, address: int, size: int, *, signed: bool = True,
             check_alert: bool = True) -> int:
        """Read ``size`` bytes at ``address`` from one servo as one little-endian integer."""
        data, error = self._exchange(servo_id, INST_READ, _le(address, 2) + _le(size, 2), size)
        self._check(servo_id, error, f"a read of address {address}", check_alert)
        return int.from_bytes(data, "little", signed=signed)

    @contextlib.contextmanager
    def permit_goals(self) -> Iterator[None]:
        """Allow Goal Position writes inside the block. Only
        :class:`~drivers.dynamixel.motion.MotionController` opens it, after its guard has
        checked the goals: no other path writes a goal position."""
        with self._lock:
            self._goal_permits += 1
        try:
            yield
        finally:
            with self._lock:
                self._goal_permits -= 1

    def _refuse_unguarded_goal(self, address: int, size: int) -> None:
        if address < Addr.GOAL_POSITION + 4 and address + size > Addr.GOAL_POSITION \
                and not self._goal_permits:
            raise LimitError(
                f"{self.port_name}: refused to write Goal Position outside the motion "
                "controller: every move goes through its guard (MotionController.move_to)"
            )

    def write(self, servo_id: int, address: int, size: int, value: int, *,
              check_alert: bool = True) -> None:
        """Write one item (``size`` bytes) and check the servo's status reply (Goal Position
        only inside :meth:`permit_goals`)."""
        self._refuse_unguarded_goal(address, size)
        _, error = self._exchange(servo_id, INST_WRITE, _le(address, 2) + _le(value, size))
        self._check(servo_id, error, f"writing {value} to address {address}", check_alert)

    def ping(self, servo_id: int) -> int:
        """Model number of ``servo_id``; :class:`ServoSilentError` if it does not answer."""
        data, _ = self._exchange(servo_id, INST_PING, (), 3)
        return int.from_bytes(data[:2], "little")

    def try_ping(self, servo_id: int, attempts: int = 1) -> int | None:
        """Model number, or None if the servo stays silent for ``attempts`` tries."""
        try:
            data, _ = self._exchange(servo_id, INST_PING, (), 3, attempts=max(1, attempts))
        except ServoSilentError:
            return None
        return int.from_bytes(data[:2], "little")

    def require(self, ids: Iterable[int]) -> dict[int, int]:
        """Ping every ID; one error listing all that are missing. Returns ``{id: model}``."""
        found: dict[int, int] = {}
        missing: list[int] = []
        for i in ids:
            model = self.try_ping(i, attempts=2)
            if model is None:
                missing.append(i)
            else:
                found[i] = model
        if missing:
            names = [f"{i} (axis '{self._axis_names[i]}')" if i in self._axis_names else str(i)
                     for i in missing]
            raise ServoSilentError(
                f"bus '{self.name}' ({self.port_name}, {self.baud} baud): no answer from servo "
                f"ID {', '.join(names)}; check power and cables, or find the servos with "
                f"`gonio scan`"
            )
        return found

    def _set_baud(self, baud: int) -> None:
        port = self._begin()
        port.ser.baudrate = baud  # pyserial reconfigures in place: the flock stays
        port.baudrate = baud
        port.tx_time_per_byte = (1000.0 / baud) * 10.0

    def scan(self, ids: Iterable[int] = range(253),
             bauds: Iterable[int] = COMMON_BAUD_RATES) -> dict[int, dict[int, int]]:
        """Find servos: ``{baud: {id: model}}`` for each baud rate where any answer.

        Uses a broadcast ping for many IDs (≈ 1.4 s per rate at 57600) and single pings for a
        few (≈ 35 ms per absent ID). The port returns to :attr:`baud` afterwards.
        """
        wanted = sorted(set(ids))
        found: dict[int, dict[int, int]] = {}
        with self._lock:
            try:
                for baud in bauds:
                    if baud not in SDK_BAUD_RATES:
                        raise ConfigError(f"bus '{self.name}': cannot scan at {baud} baud; use "
                                          f"one of {', '.join(map(str, COMMON_BAUD_RATES))}")
                    self._set_baud(baud)
                    hits: dict[int, int] = {}
                    if len(wanted) > 8:
                        port = self._begin()
                        data, _ = self._ph.broadcastPing(port)
                        hits = {i: v[0] for i, v in data.items() if i in wanted}
                    else:
                        for i in wanted:
                            result, data, _ = self._exchange_once(i, INST_PING, [], 3)
                            if result == COMM_SUCCESS:
                                hits[i] = int.from_bytes(data[:2], "little")
                    if hits:
                        found[baud] = hits
            finally:
                self._set_baud(self.baud)
        return found

    # ------------------------------------------------------------------ group I/O
    def sync_read(self, ids: Iterable[int], address: int, size: int, *,
                  check_alert: bool = True) -> dict[int, bytes]:
        """One SYNC_READ of ``size`` bytes at ``address``: ``{id: raw bytes}``.

        Missing or corrupt replies are asked for again (only those servos), up to
        :attr:`retries` times.
        """
        wanted = list(dict.fromkeys(ids))
        if not wanted:
            return {}
        got: dict[int, tuple[bytes, int]] = {}
        remaining = list(wanted)
        result = COMM_TX_FAIL
        for attempt in range(self.retries + 1):
            with self._lock:
                self._count(remaining, "retries" if attempt else "requests")
                if attempt:
                    self._pause(attempt)
                result = self._sync_read_once(remaining, address, size, got)
            remaining = [i for i in remaining if i not in got]
            if not remaining:
                break
        else:
            raise self._silent(remaining, result, self.retries + 1)
        for i in wanted:
            self._check(i, got[i][1], f"a sync read of address {address}", check_alert)
        return {i: got[i][0] for i in wanted}

    def _sync_read_once(self, ids: list[int], address: int, size: int,
                        got: dict[int, tuple[bytes, int]]) -> int:
        port = self._begin()
        try:
            result = self._ph.syncReadTx(port, address, size, ids, len(ids), False)
            if result != COMM_SUCCESS:
                return result
            port.packet_timeout += self.reply_grace_ms  # syncReadTx set the SDK's timeout
            pending = set(ids)
            corrupt = 0
            # Each call returns one packet, a corrupt one, or the timeout; bound the loop.
            for _ in range(2 * len(ids) + 4):
                self._wait_for_reply(port)
                packet, result = self._ph.rxPacket(port, False)
                if result == COMM_SUCCESS:
                    sid, error = packet[4], packet[8]
                    length = (packet[5] | (packet[6] << 8)) - 4
                    if sid not in pending or (error & ~ALERT_BIT) == ERRNUM_CRC:
                        continue
                    if not (error & ~ALERT_BIT) and length != size:
                        continue  # a late reply to an older request
                    got[sid] = (bytes(packet[9 : 9 + size]), error)
                    pending.discard(sid)
                elif result == COMM_RX_CORRUPT:
                    corrupt += 1
                else:
                    return result
                if len(pending) <= corrupt:
                    # Every servo has answered (some garbled): no point waiting for the timeout.
                    return COMM_SUCCESS if not pending else COMM_RX_CORRUPT
            return COMM_RX_TIMEOUT
        except (serial.SerialException, OSError):
            return COMM_TX_FAIL
        finally:
            port.is_using = False

    def sync_write(self, address: int, size: int, values: Mapping[int, int]) -> None:
        """One SYNC_WRITE of ``size``-byte ``values`` ``{id: value}`` (no reply expected; Goal
        Position only inside :meth:`permit_goals`)."""
        if not values:
            return
        self._refuse_unguarded_goal(address, size)
        result = COMM_TX_FAIL
        for attempt in range(self.retries + 1):
            with self._lock:
                self._count(values, "retries" if attempt else "requests")
                if attempt:
                    self._pause(attempt)
                port = self._begin()
                group = GroupSyncWrite(port, self._ph, address, size)
                for sid, value in values.items():
                    group.addParam(sid, _le(int(value), size))
                try:
                    result = group.txPacket()
                except (serial.SerialException, OSError):
                    result = COMM_TX_FAIL
                port.is_using = False
                if result == COMM_SUCCESS:
                    return
        raise CommunicationError(
            f"bus '{self.name}' ({self.port_name}): could not send a sync write "
            f"({comm_text(result)}); check the USB adapter"
        )

    # ------------------------------------------------------------------ errors
    def _check(self, servo_id: int, error: int, what: str, check_alert: bool) -> None:
        if error & ~ALERT_BIT:
            raise self._refused(servo_id, error, what)
        if error & ALERT_BIT and check_alert:
            raise self.hardware_error_of(servo_id)

    def hardware_error_of(self, servo_id: int) -> codes.ServoHardwareError:
        """Read Hardware Error Status (plus temperature, voltage) and build the typed error."""
        # Shutdown (63) .. Hardware Error Status (70), then voltage (144) .. temperature (146).
        safety = self.read(servo_id, Addr.SHUTDOWN, 8, signed=False, check_alert=False)
        power = self.read(servo_id, Addr.PRESENT_INPUT_VOLTAGE, 3, signed=False,
                          check_alert=False)
        shutdown, bits = safety & 0xFF, safety >> 56
        volts, temp = (power & 0xFFFF) / 10, power >> 16
        return hardware_error(
            bits, self.describe(servo_id), servo_id=servo_id,
            axis=self._axis_names.get(servo_id), detail=f"{temp} °C, {volts:.1f} V",
            shutdown=shutdown,
        )

    # ------------------------------------------------------------------ servo-level verbs
    def set_torque(self, ids: Iterable[int], on: bool) -> None:
        """Torque on/off for each servo (acknowledged writes). Turning torque on while a
        hardware error is latched raises the typed hardware error."""
        for sid in ids:
            try:
                self.write(sid, Addr.TORQUE_ENABLE, 1, int(bool(on)), check_alert=not on)
            except ServoCommandError:
                bits = self.read(sid, Addr.HARDWARE_ERROR_STATUS, 1, signed=False,
                                 check_alert=False)
                if on and bits:
                    raise self.hardware_error_of(sid) from None
                raise

    def write_goals(self, goals: Mapping[int, int]) -> None:
        """Goal Position (ticks) for several servos in ONE sync write (no reply: confirm it by
        reading the goal back)."""
        self.sync_write(Addr.GOAL_POSITION, 4, goals)

    def resend_goals(self, goals: Mapping[int, int], lost: Iterable[int] | None = None) -> None:
        """Send again, in ONE sync write, goals (ticks) of a move whose read-back showed some
        never arrived; the servos in ``lost`` (default: all) are counted as resends."""
        lost = list(goals if lost is None else lost)
        with self._lock:
            self._count(lost, "resends")
            self.stats["resends"] += len(lost)
        self.sync_write(Addr.GOAL_POSITION, 4, goals)

    def write_goal(self, servo_id: int, goal: int, *, resend: bool = False) -> None:
        """Goal Position (ticks) of one servo in an acknowledged WRITE: its status packet
        proves it arrived (retried like any transfer). ``resend`` counts it as a resend."""
        if resend:
            with self._lock:
                self._count([servo_id], "resends")
                self.stats["resends"] += 1
        self.write(servo_id, Addr.GOAL_POSITION, 4, goal)

    def read_positions(self, ids: Iterable[int]) -> dict[int, int]:
        """Present Position (signed ticks) of several servos in ONE sync read."""
        raw = self.sync_read(ids, Addr.PRESENT_POSITION, 4)
        return {i: _int(b, 0, 4) for i, b in raw.items()}

    def read_moving(self, ids: Iterable[int]) -> dict[int, bool]:
        """Moving flag of several servos in ONE sync read."""
        raw = self.sync_read(ids, Addr.MOVING, 1)
        return {i: bool(b[0]) for i, b in raw.items()}

    def read_motion(self, ids: Iterable[int]) -> dict[int, MotionSample]:
        """Goal, moving, velocity, position (116–135) of several servos in ONE sync read."""
        raw = self.sync_read(ids, Addr.GOAL_POSITION, 20)
        return {
            i: MotionSample(goal=_int(b, 0, 4), moving=bool(b[6]), velocity=_int(b, 12, 4),
                            position=_int(b, 16, 4))
            for i, b in raw.items()
        }

    def read_status(self, ids: Iterable[int]) -> dict[int, ServoStatus]:
        """Everything an operator's status table needs (64–147) in ONE sync read.

        Does not raise on hardware errors: they are reported in ``hardware_error``.
        """
        base = Addr.TORQUE_ENABLE
        raw = self.sync_read(ids, base, 84, check_alert=False)
        out = {}
        for i, b in raw.items():
            out[i] = ServoStatus(
                position=_int(b, Addr.PRESENT_POSITION - base, 4),
                goal=_int(b, Addr.GOAL_POSITION - base, 4),
                moving=bool(b[Addr.MOVING - base]),
                temperature_c=b[Addr.PRESENT_TEMPERATURE - base],
                voltage_v=_int(b, Addr.PRESENT_INPUT_VOLTAGE - base, 2, signed=False) / 10,
                hardware_error=b[Addr.HARDWARE_ERROR_STATUS - base],
                torque_on=bool(b[0]),
            )
        return out

    def read_safety(self, ids: Iterable[int]) -> dict[int, tuple[bool, int]]:
        """(torque on, Hardware Error Status) per servo (64–70) in ONE sync read."""
        raw = self.sync_read(ids, Addr.TORQUE_ENABLE, 7, check_alert=False)
        return {i: (bool(b[0]), b[6]) for i, b in raw.items()}

    def set_profile(self, servo_id: int, velocity: int, acceleration: int) -> None:
        """Profile Velocity (0.229 rev/min units) and Acceleration (214.577 rev/min² units)
        in one write (addresses 108–115); 0 means unlimited."""
        for value, what in ((velocity, "velocity"), (acceleration, "acceleration")):
            if not 0 <= value <= 32767:
                raise ConfigError(f"{self.describe(servo_id)}: profile {what} {value} is outside "
                                  f"0..32767 (X-series units)")
        params = _le(Addr.PROFILE_ACCELERATION, 2) + _le(acceleration, 4) + _le(velocity, 4)
        _, error = self._exchange(servo_id, INST_WRITE, params)
        self._check(servo_id, error, "a profile write", True)

    def set_return_delay(self, ids: Iterable[int], value: int = 0) -> None:
        """Return Delay Time (unit 2 µs; EEPROM, so torque must be off). 0 for low latency."""
        for sid in ids:
            self.write(sid, Addr.RETURN_DELAY_TIME, 1, value, check_alert=False)

    def reboot(self, servo_id: int, timeout_s: float = 2.0) -> None:
        """REBOOT one servo (clears latched hardware errors whose cause is gone; torque comes
        back off) and wait until it answers again."""
        self._exchange(servo_id, INST_REBOOT)
        deadline = time.monotonic() + timeout_s
        while self.try_ping(servo_id) is None:
            if time.monotonic() > deadline:
                raise self._silent([servo_id], COMM_RX_TIMEOUT, 1)
