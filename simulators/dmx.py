"""A simulated Enttec DMX USB Pro widget behind a real pseudo-terminal.

Any client (``drivers.dmx.DmxWidget``, pyserial, a terminal program, a third-party Enttec
library) opens :meth:`SimDmxWidget.start`'s path like a USB widget. The simulator parses the
host's frames strictly (``0x7E, label, length LSB, length MSB, data, 0xE7``) and implements
every request of the DMX USB Pro API 1.44 the way the widget's firmware does:

* 3 Get Widget Parameters: replies with firmware version, break, MAB, output rate and the
  requested user-configuration bytes.
* 4 Set Widget Parameters: break (9–127 × 10.67 µs), MAB (1–127 × 10.67 µs), output rate
  (0–40 packets/s, 0 = as fast as the line allows) and user configuration (≤ 508 bytes); no
  reply. Later frames use them and label 3 echoes them; they persist for the widget's life.
* 6 Output Only Send DMX Packet: the widget outputs the packet periodically (timing below).
* 8 Receive DMX on Change (DMX firmware): selects label 5 ("send always", the default) or
  label 9 (changes only) for packets received on the DMX port and clears the change baseline.
* 7 Send RDM Packet and 11 Send RDM Discovery Request (RDM firmware): the packet goes out on
  the line (:meth:`SimDmxWidget.sim_rdm_sent`) and the port turns to input. The simulated line
  has no RDM responder, so nothing comes back unless a test plays one with
  :meth:`SimDmxWidget.sim_line_input`, whose packet reaches the host as label 5.
* 10 Get Widget Serial Number: replies with 4 BCD bytes, least significant first.
* 1 Reprogram Firmware enters the bootstrap, which then only answers 2 Program Flash Page
  (``TRUE`` for a 64-byte page; ``FALS`` for any other size or outside the bootstrap). The
  bootstrap lasts until the simulator stops (it has no firmware to restart into).

As the API specifies, the periodic output stops and the port turns to input on any handled
request other than labels 6 and 3; fixtures keep showing the last universe that went out.
Labels the firmware variety does not support (7 and 11 on DMX firmware 0x01xx, 8 on RDM
firmware 0x02xx), labels only the widget sends (5, 9) and unknown labels are ignored without a
reply, like the real widget. Malformed or refused input is counted per kind
(:meth:`SimDmxWidget.sim_errors`) and otherwise ignored.

While the port is an input, packets played onto the line with :meth:`SimDmxWidget.sim_line_input`
reach the host as label 5 (status byte, start code, slots) or, in change-only mode, as label 9
change-of-state messages (byte 0 = start code; alternate start codes are not reported).

Output timing model: a frame is break + MAB + (start code + ≥ 24 slots) × 44 µs (250 kbaud, 11
bits per slot); frames start every ``max(frame time, 1 / output rate)`` (back to back at rate 0).
Output starts with the first frame when a packet arrives while the port is idle; afterwards a
universe received at time t goes out in the first frame starting at or after t and counts as
*active* once that frame is complete; a universe replaced before its frame started, or whose
frame never started because the output stopped, is never output (``dropped``).
:meth:`SimDmxWidget.sim_state_at` answers what the fixtures were showing at a given time.

It imports nothing from :mod:`drivers`: it parses the protocol itself, independently of the
driver. It reports through return values and :mod:`logging` (logger ``simulators.dmx``).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import select
import signal
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TextIO

from simulators.clock import SimClock

log = logging.getLogger(__name__)

_START = 0x7E
_END = 0xE7
_MAX_LENGTH = 600
_SLOT_S = 11 / 250_000
_UNIT_S = 10.67e-6
_MIN_SLOTS = 24
_MAX_SLOTS = 512
_USER_CONFIG_BYTES = 508
_FLASH_PAGE_BYTES = 64
_DISCOVERY_BYTES = 38  # a DISC_UNIQUE_BRANCH request
_HOST_QUEUE_BYTES = 64 * 1024  # unread widget→host bytes beyond which received packets are lost
_DMX_FIRMWARE, _RDM_FIRMWARE = 1, 2

ERROR_KINDS = ("start_byte", "length", "end_byte", "label", "start_code", "value")
"""Keys of :meth:`SimDmxWidget.sim_errors`: bytes outside a frame (one per run), a length
field out of range for its label, a wrong end byte, a label the firmware does not handle, DMX
packets with a non-zero start code (output, but ignored by dimmers), and a field out of its
valid range (Set Widget Parameters, Receive DMX on Change): the request is ignored."""


@dataclass(frozen=True)
class SimDmxState:
    """One universe the simulated widget received.

    Attributes
    ----------
    levels:
        Channel levels exactly as sent (channel 1 first, start code removed).
    received_s:
        Clock time the frame was parsed (s).
    output_start_s:
        Start of the DMX frame that carries it (s).
    active_s:
        Time the fixtures have all its levels: end of that frame (s).
    dropped:
        True if it was never output: replaced by a newer packet, or the output stopped,
        before its frame started.
    """

    levels: bytes
    received_s: float
    output_start_s: float
    active_s: float
    dropped: bool = False


class _HostClock:
    def now(self) -> float:
        return time.monotonic()


class SimDmxWidget:
    """Simulated DMX USB Pro on a pty; one instance per universe.

    Parameters
    ----------
    clock:
        Shared simulated clock; host monotonic time if None.
    serial_number:
        Serial number reported by label 10 (up to 8 decimal digits).
    firmware:
        16-bit firmware version reported by label 3; its MSB is the variety: 1 = DMX firmware,
        2 = RDM firmware (the RDM sniffer firmware is not simulated).
    break_units, mab_units:
        Initial break (9–127) and mark-after-break (1–127) times (× 10.67 µs).
    refresh_rate_hz:
        Initial DMX output rate (packets/s, 1–40; 0 = as fast as the line allows).
    user_config:
        Initial user configuration bytes (≤ 508; the rest reads as zeros).
    """

    def __init__(
        self,
        *,
        clock: SimClock | None = None,
        serial_number: int = 12345678,
        firmware: int = 0x0144,
        break_units: int = 9,
        mab_units: int = 1,
        refresh_rate_hz: int = 40,
        user_config: bytes = b"",
    ) -> None:
        if not 0 <= serial_number <= 99_999_999:
            raise ValueError(f"serial_number must have ≤ 8 decimal digits, got {serial_number}")
        if not (0 <= firmware <= 0xFFFF and firmware >> 8 in (_DMX_FIRMWARE, _RDM_FIRMWARE)):
            raise ValueError(f"firmware must be 0x01xx (DMX) or 0x02xx (RDM), got {firmware:#x}")
        if not _valid_parameters(break_units, mab_units, refresh_rate_hz):
            raise ValueError("break_units must be 9–127, mab_units 1–127, refresh_rate_hz 0–40")
        if len(user_config) > _USER_CONFIG_BYTES:
            raise ValueError(f"user_config holds at most {_USER_CONFIG_BYTES} bytes")
        self._clock = clock if clock is not None else _HostClock()
        self._serial_number = serial_number
        self._firmware = firmware
        self._break_units = break_units
        self._mab_units = mab_units
        self._rate_hz = refresh_rate_hz
        self._user_config = bytearray(user_config.ljust(_USER_CONFIG_BYTES, b"\0"))
        self._lock = threading.Lock()
        self._buf = bytearray()
        self._skipping = False
        self._errors = dict.fromkeys(ERROR_KINDS, 0)
        self._received: dict[int, int] = {}
        self._history: list[SimDmxState] = []
        # output schedule: frames start at _anchor_s + k × _anchor_period_s while outputting
        self._outputting = False
        self._anchor_s = 0.0
        self._anchor_period_s = 0.0
        self._anchor_wire_s = 0.0
        self._line_free_s = -math.inf
        # input side
        self._on_change = False
        self._rx_last = bytearray(1 + _MAX_SLOTS)
        self._rx_overflow = False
        self._rdm_sent: list[bytes] = []
        self._bootstrap = False
        self._out = bytearray()  # widget → host bytes not yet written to the pty
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._thread: threading.Thread | None = None
        self._path: str | None = None
        self._started = False
        self._stopping = False
        self._busy = False
        self._handlers: dict[int, Callable[[bytes, float], bool]] = {
            1: self._reprogram_firmware,
            2: self._program_flash_page,
            3: self._get_parameters,
            4: self._set_parameters,
            6: self._send_dmx,
            7: self._send_rdm,
            8: self._receive_on_change,
            10: self._get_serial_number,
            11: self._send_rdm_discovery,
        }
        if firmware >> 8 == _DMX_FIRMWARE:
            del self._handlers[7], self._handlers[11]
        else:
            del self._handlers[8]

    # -- lifecycle -----------------------------------------------------------------------------

    def start(self) -> str:
        """Open the pty and serve it from a thread; returns the device path for clients."""
        if self._started:
            raise RuntimeError("SimDmxWidget can be started once; make a new one")
        self._started = True
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo or line editing before the client configures it
        os.set_blocking(self._master, False)
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)  # a full pipe already means "wake up"
        self._path = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._serve, name=f"sim-dmx {self._path}")
        self._thread.daemon = True
        self._thread.start()
        return self._path

    @property
    def path(self) -> str | None:
        """The pty path while running, else None."""
        return self._path

    def stop(self) -> None:
        """Stop serving and close the pty (idempotent); clients then see a disconnect."""
        self._stopping = True
        with self._lock:
            self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._thread = None
        with self._lock:
            for name in ("_master", "_slave", "_wake_r", "_wake_w"):
                fd = getattr(self, name)
                if fd is not None:
                    os.close(fd)
                    setattr(self, name, None)
        self._path = None

    def sim_unplug(self) -> None:
        """Pull the USB cable: the pty disappears and the client's next read/write fails."""
        self.stop()

    def __enter__(self) -> SimDmxWidget:
        if not self._started:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- sim-only inspection and stimuli -------------------------------------------------------

    def sim_errors(self) -> dict[str, int]:
        """Malformed or ignored input so far, counted per kind (see :data:`ERROR_KINDS`)."""
        with self._lock:
            return dict(self._errors)

    def sim_received(self) -> dict[int, int]:
        """Frames of a handled label with a valid length received so far, counted per label."""
        with self._lock:
            return dict(self._received)

    def sim_summary(self) -> str:
        """One line: frames received and malformed/ignored input per kind."""
        errors = {k: v for k, v in self.sim_errors().items() if v}
        received = sum(self.sim_received().values())
        return f"sim dmx: {received} frames received, malformed/ignored: {errors or 'none'}"

    def sim_is_outputting(self) -> bool:
        """Whether the port is outputting DMX (else it is an input)."""
        with self._lock:
            return self._outputting

    def sim_in_bootstrap(self) -> bool:
        """Whether a Reprogram Firmware request put the widget into its bootstrap."""
        with self._lock:
            return self._bootstrap

    def sim_rdm_sent(self) -> list[bytes]:
        """RDM packets (labels 7 and 11) sent out on the line, oldest first, as the host gave them."""
        with self._lock:
            return list(self._rdm_sent)

    def sim_line_input(self, slots: bytes, start_code: int = 0) -> bool:
        """Play a packet (``start_code`` + up to 512 ``slots``) onto the widget's DMX port.

        It stands for another controller (or an RDM responder) on the line. The widget passes it
        to the host only while its port is an input; returns whether it did. A host that does
        not read loses packets, flagged in the next label 5's status byte (queue overflowed).
        """
        if len(slots) > _MAX_SLOTS or not 0 <= start_code <= 255:
            raise ValueError("a DMX packet is a start code 0–255 and at most 512 slots")
        packet = bytes((start_code,)) + bytes(slots)
        with self._lock:
            if self._outputting or self._bootstrap or self._master is None:
                return False
            if not self._on_change:
                status = 1 if self._rx_overflow else 0
                self._rx_overflow = False
                self._to_host(_frame(5, bytes((status,)) + packet), droppable=True)
            elif start_code == 0:
                for message in _changes(self._rx_last, packet):
                    self._to_host(_frame(9, message), droppable=True)
            self._wake()
        return True

    def sim_universe(self) -> bytes:
        """Levels of the last universe received, exactly as sent (b"" before any)."""
        with self._lock:
            return self._history[-1].levels if self._history else b""

    def sim_history(self) -> list[SimDmxState]:
        """Every universe received, oldest first."""
        with self._lock:
            return list(self._history)

    def sim_state_at(self, t: float) -> bytes:
        """Levels the fixtures showed at clock time ``t`` (s): the last universe active by then.

        Channels beyond the returned length are not driven (b"" before the first universe).
        """
        with self._lock:
            for state in reversed(self._history):
                if not state.dropped and state.active_s <= t:
                    return state.levels
        return b""

    def sim_states_during(self, t0: float, t1: float) -> list[bytes]:
        """Every universe the fixtures showed during [t0, t1] (s), oldest first.

        One entry means the light was constant over the interval (e.g. an exposure).
        """
        states = [self.sim_state_at(t0)]
        with self._lock:
            states += [
                h.levels for h in self._history if not h.dropped and t0 < h.active_s <= t1
            ]
        return states

    def sim_wait_idle(self, timeout_s: float = 2.0) -> bool:
        """Block until every byte written to the pty so far has been parsed (host time).

        Returns False on timeout or when not running. For tests that step a shared clock.
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            master = self._master
            if master is None:
                return False
            try:
                # poll() on a tty first flushes the kernel's deferred pty buffer, so unlike
                # FIONREAD it sees bytes the client's write() has already returned for
                pending, _, _ = select.select([master], [], [], 0)
            except (OSError, ValueError):
                return False
            # order matters: the thread sets _busy before it reads, so "nothing pending,
            # then not busy" means every byte was read and fully parsed
            if not pending and not self._busy:
                return True
            time.sleep(50e-6)
        return False

    def sim_frame_time_s(self, n_channels: int = _MAX_SLOTS) -> float:
        """Wire time of one output frame of ``n_channels`` with the current parameters (s)."""
        slots = 1 + max(_MIN_SLOTS, n_channels)
        return (self._break_units + self._mab_units) * _UNIT_S + slots * _SLOT_S

    def sim_frame_period_s(self, n_channels: int = _MAX_SLOTS) -> float:
        """Spacing of output frame starts for a universe of ``n_channels`` (s)."""
        wire = self.sim_frame_time_s(n_channels)
        return max(wire, 1.0 / self._rate_hz) if self._rate_hz else wire

    # -- serving -------------------------------------------------------------------------------

    def _serve(self) -> None:
        assert self._master is not None and self._wake_r is not None
        master, wake = self._master, self._wake_r
        while True:
            writing = [master] if self._out else []
            ready, writable, _ = select.select([master, wake], writing, [])
            if wake in ready:
                with contextlib.suppress(BlockingIOError):
                    os.read(wake, 64)
                if self._stopping:
                    return
            if master in ready:
                self._busy = True  # before reading: see sim_wait_idle
                try:
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        continue
                    except OSError:
                        return
                    if not data:
                        return
                    self._feed(data)
                finally:
                    self._busy = False
            if self._out:
                self._flush()

    def _wake(self) -> None:
        """Make the serving thread look at its queue and flags (lock held: fds stay open)."""
        if self._wake_w is not None:
            with contextlib.suppress(BlockingIOError):
                os.write(self._wake_w, b"w")

    def _to_host(self, frame: bytes, *, droppable: bool = False) -> None:
        """Queue a widget → host frame (lock held); received packets are lost on overflow."""
        if droppable and len(self._out) + len(frame) > _HOST_QUEUE_BYTES:
            self._rx_overflow = True
            return
        self._out += frame

    def _flush(self) -> None:
        with self._lock:
            if not self._out or self._master is None:
                return
            try:
                n = os.write(self._master, self._out)
            except BlockingIOError:
                return  # the client is not reading: keep the bytes for later
            except OSError:
                n = len(self._out)  # pty gone: nobody will read them
            del self._out[:n]

    def _feed(self, data: bytes) -> None:
        now = self._clock.now()
        with self._lock:
            buf = self._buf
            buf += data
            while buf:
                if buf[0] != _START:
                    i = buf.find(_START)
                    if not self._skipping:
                        self._errors["start_byte"] += 1
                    del buf[: len(buf) if i < 0 else i]
                    self._skipping = i < 0
                    continue
                self._skipping = False
                if len(buf) < 4:
                    break
                length = buf[2] | buf[3] << 8
                if length > _MAX_LENGTH:
                    self._reject("length", 1)
                    continue
                if len(buf) < length + 5:
                    break
                if buf[length + 4] != _END:
                    self._reject("end_byte", length + 5)
                    continue
                label, payload = buf[1], bytes(buf[4 : length + 4])
                del buf[: length + 5]
                self._handle(label, payload, now)

    def _reject(self, kind: str, drop: int) -> None:
        self._errors[kind] += 1
        del self._buf[:drop]
        self._skipping = True  # bytes up to the next 0x7E belong to the bad frame

    # -- requests (lock held) ------------------------------------------------------------------

    def _handle(self, label: int, payload: bytes, now: float) -> None:
        handler = self._handlers.get(label)
        if handler is None or (self._bootstrap and label != 2):
            self._errors["label"] += 1  # unsupported: ignored without a reply
            return
        if handler(payload, now) and label not in (3, 6):
            self._stop_output(now)  # any other request turns the port to input

    def _valid_length(self, label: int, payload: bytes, ok: bool) -> bool:
        """Count a frame as received if its length is valid, else as a length error."""
        if not ok:
            self._errors["length"] += 1
            return False
        self._received[label] = self._received.get(label, 0) + 1
        return True

    def _reprogram_firmware(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(1, payload, not payload):
            return False
        self._bootstrap = True
        return True

    def _program_flash_page(self, payload: bytes, now: float) -> bool:
        self._received[2] = self._received.get(2, 0) + 1
        ok = self._bootstrap and len(payload) == _FLASH_PAGE_BYTES
        self._to_host(_frame(2, b"TRUE" if ok else b"FALS"))
        return True

    def _get_parameters(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(3, payload, len(payload) == 2):
            return False
        size = min(payload[0] | payload[1] << 8, _USER_CONFIG_BYTES)
        fw = self._firmware
        fields = (fw & 0xFF, fw >> 8, self._break_units, self._mab_units, self._rate_hz)
        self._to_host(_frame(3, bytes(fields) + bytes(self._user_config[:size])))
        return True

    def _set_parameters(self, payload: bytes, now: float) -> bool:
        n = len(payload)
        size = payload[0] | payload[1] << 8 if n >= 2 else 0
        if not self._valid_length(4, payload, n >= 5 and n == 5 + size):
            return False
        brk, mab, rate = payload[2:5]
        if size > _USER_CONFIG_BYTES or not _valid_parameters(brk, mab, rate):
            self._errors["value"] += 1
            return False
        self._break_units, self._mab_units, self._rate_hz = brk, mab, rate
        self._user_config[:size] = payload[5:]
        return True

    def _send_dmx(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(6, payload, 1 + _MIN_SLOTS <= len(payload) <= 1 + _MAX_SLOTS):
            return False
        levels = payload[1:]
        start, active = self._schedule(len(levels), now)
        if payload[0] != 0:
            self._errors["start_code"] += 1  # on the wire, but not a dimmer universe
            return True
        self._history.append(SimDmxState(levels, now, start, active))
        return True

    def _send_rdm(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(7, payload, 1 <= len(payload) <= 1 + _MAX_SLOTS):
            return False
        self._rdm_sent.append(payload)  # no responder on the simulated line: no reply
        return True

    def _send_rdm_discovery(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(11, payload, len(payload) == _DISCOVERY_BYTES):
            return False
        self._rdm_sent.append(payload)  # no responder on the simulated line: no reply
        return True

    def _receive_on_change(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(8, payload, len(payload) == 1):
            return False
        if payload[0] > 1:
            self._errors["value"] += 1
            return False
        self._on_change = payload[0] == 1
        self._rx_last[:] = bytes(len(self._rx_last))  # the change baseline restarts at zeros
        return True

    def _get_serial_number(self, payload: bytes, now: float) -> bool:
        if not self._valid_length(10, payload, not payload):
            return False
        digits = f"{self._serial_number:08d}"
        self._to_host(_frame(10, bytes(int(digits[i : i + 2], 16) for i in range(6, -1, -2))))
        return True

    # -- output timing (lock held) -------------------------------------------------------------

    def _schedule(self, n_channels: int, now: float) -> tuple[float, float]:
        """Start and end (s) of the frame that carries a packet of ``n_channels`` received now.

        A pending universe whose frame had not started yet is replaced (dropped).
        """
        if self._outputting:
            k = max(0, math.ceil((now - self._anchor_s) / self._anchor_period_s - 1e-9))
            start = self._anchor_s + k * self._anchor_period_s
        else:
            start = max(now, self._line_free_s)  # an idle port starts a frame at once
            self._outputting = True
        last = self._history[-1] if self._history else None
        if last is not None and not last.dropped and last.output_start_s >= start:
            self._history[-1] = replace(last, dropped=True)
        self._anchor_s = start
        self._anchor_wire_s = self.sim_frame_time_s(n_channels)
        self._anchor_period_s = self.sim_frame_period_s(n_channels)
        return start, start + self._anchor_wire_s

    def _stop_output(self, now: float) -> None:
        """Stop the periodic output at ``now``; the frame on the wire, if any, completes."""
        if not self._outputting:
            return
        self._outputting = False
        if now < self._anchor_s:  # the newest packet's frame never starts
            last = self._history[-1] if self._history else None
            if last is not None and last.output_start_s >= self._anchor_s:
                self._history[-1] = replace(last, dropped=True)
            self._line_free_s = self._anchor_s  # the frame before it ends by then
            return
        k = math.floor((now - self._anchor_s) / self._anchor_period_s)
        self._line_free_s = max(now, self._anchor_s + k * self._anchor_period_s + self._anchor_wire_s)


def _valid_parameters(break_units: int, mab_units: int, rate_hz: int) -> bool:
    return 9 <= break_units <= 127 and 1 <= mab_units <= 127 and 0 <= rate_hz <= 40


def _frame(label: int, data: bytes) -> bytes:
    n = len(data)
    return bytes((_START, label, n & 0xFF, n >> 8)) + data + bytes((_END,))


def _changes(last: bytearray, packet: bytes) -> list[bytes]:
    """Label-9 messages turning ``last`` into ``packet`` (start code at index 0); updates ``last``.

    Each message covers 40 bytes from an 8-byte block: the block number, a 40-bit changed mask
    (bit i = byte block × 8 + i, little-endian) and the changed bytes in order.
    """
    messages: list[bytes] = []
    n, i = len(packet), 0
    while i < n:
        if packet[i] == last[i]:
            i += 1
            continue
        block = i // 8
        window = range(block * 8, min(block * 8 + 40, n))
        changed = [k for k in window if packet[k] != last[k]]
        mask = sum(1 << (k - block * 8) for k in changed)
        messages.append(bytes((block,)) + mask.to_bytes(5, "little") + bytes(packet[k] for k in changed))
        i = window.stop
    last[:n] = packet
    return messages


def serve_dmx_forever(
    *,
    serial_number: int = 12345678,
    refresh_rate_hz: int = 40,
    time_scale: float = 1.0,
    out: TextIO,
    err: TextIO,
) -> int:
    """Run one simulated widget until SIGINT/SIGTERM; its device path is the first line of ``out``.

    The path goes to ``out`` (the caller's stdout), flushed at once so a parent process can read it. On
    exit :meth:`SimDmxWidget.sim_summary` is logged (logger ``simulators.dmx``); while this
    runs, that logger also writes to ``err``. Must run in the main thread. Returns the
    exit code (0).
    """
    handler = logging.StreamHandler(err)
    log.addHandler(handler)
    level = log.level
    log.setLevel(logging.INFO)
    sigs = {signal.SIGINT, signal.SIGTERM}
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)  # the sim thread inherits it
    try:
        sim = SimDmxWidget(
            clock=SimClock(time_scale), serial_number=serial_number, refresh_rate_hz=refresh_rate_hz
        )
        with sim:
            out.write(f"{sim.path}\n")
            out.flush()
            signal.sigwait(sigs)
        log.info(sim.sim_summary())
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
        log.removeHandler(handler)
        log.setLevel(level)
    return 0
