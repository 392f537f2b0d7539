"""A simulated Enttec DMX USB Pro widget behind a real pseudo-terminal.

Any client (``drivers.dmx.DmxWidget``, pyserial, a terminal program) opens :meth:`start`'s
path like a USB widget. The simulator parses the host's frames strictly
(``0x7E, label, length LSB, length MSB, data, 0xE7``): a byte where a frame should start, a
length out of range, a wrong end byte or an unsupported label is counted per kind
(:meth:`SimDmxWidget.sim_errors`) and otherwise ignored, like a real widget. It supports
labels 6 (Output Only Send DMX Packet), 3 (Get Widget Parameters) and 10 (Get Widget Serial
Number); Set Widget Parameters (4) is not simulated and counts as an unsupported label.

Output timing model: the widget starts a DMX frame every ``1 / refresh_rate_hz`` seconds from
:meth:`start`. A universe received at time t goes out in the first frame starting at or after
t and counts as *active* once that frame is complete (start + break + MAB + slots × 44 µs);
a universe replaced before its frame started is never output (``dropped``).
:meth:`sim_state_at` answers what the fixtures were showing at a given time.
It imports nothing from :mod:`drivers`: it parses the protocol itself, independently of the driver.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import signal
import sys
import threading
import time
import tty
from dataclasses import dataclass, replace
from typing import TextIO

from simulators.clock import SimClock

_START = 0x7E
_END = 0xE7
_MAX_LENGTH = 600
_SLOT_S = 11 / 250_000
_UNIT_S = 10.67e-6

ERROR_KINDS = ("start_byte", "length", "end_byte", "label", "start_code")
"""Keys of :meth:`SimDmxWidget.sim_errors`: bytes outside a frame (one per run), a length
field out of range for its label, a wrong end byte, an unsupported label, and DMX packets
with a non-zero start code (output, but ignored by dimmers)."""


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
        True if a newer universe replaced it before it was output.
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
        16-bit firmware version reported by label 3 (MSB 1 = DMX firmware).
    break_units, mab_units:
        Break and mark-after-break times (× 10.67 µs).
    refresh_rate_hz:
        DMX output rate (packets/s, 1–40).
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
    ) -> None:
        if not 0 <= serial_number <= 99_999_999:
            raise ValueError(f"serial_number must have ≤ 8 decimal digits, got {serial_number}")
        if not 1 <= refresh_rate_hz <= 40:
            raise ValueError(f"refresh_rate_hz must be 1–40, got {refresh_rate_hz}")
        if not (9 <= break_units <= 127 and 1 <= mab_units <= 127):
            raise ValueError("break_units must be 9–127 and mab_units 1–127")
        self._clock = clock if clock is not None else _HostClock()
        self._serial_number = serial_number
        self._firmware = firmware
        self._break_units = break_units
        self._mab_units = mab_units
        self._rate_hz = refresh_rate_hz
        self._lock = threading.Lock()
        self._buf = bytearray()
        self._skipping = False
        self._errors = dict.fromkeys(ERROR_KINDS, 0)
        self._received: dict[int, int] = {}
        self._history: list[SimDmxState] = []
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r: int | None = None
        self._wake_w: int | None = None
        self._thread: threading.Thread | None = None
        self._path: str | None = None
        self._t0 = 0.0
        self._started = False
        self._busy = False

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
        self._path = os.ttyname(self._slave)
        self._t0 = self._clock.now()
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
        if self._wake_w is not None:
            os.write(self._wake_w, b"x")
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join()
        self._thread = None
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

    # -- sim-only inspection -------------------------------------------------------------------

    def sim_errors(self) -> dict[str, int]:
        """Malformed or ignored input so far, counted per kind (see :data:`ERROR_KINDS`)."""
        with self._lock:
            return dict(self._errors)

    def sim_received(self) -> dict[int, int]:
        """Well-formed frames received so far, counted per label."""
        with self._lock:
            return dict(self._received)

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

    def sim_frame_time_s(self, n_channels: int = 512) -> float:
        """Wire time of one output frame of ``n_channels`` (s)."""
        slots = 1 + max(24, n_channels)
        return (self._break_units + self._mab_units) * _UNIT_S + slots * _SLOT_S

    # -- serving -------------------------------------------------------------------------------

    def _serve(self) -> None:
        assert self._master is not None and self._wake_r is not None
        master, wake = self._master, self._wake_r
        while True:
            ready, _, _ = select.select([master, wake], [], [])
            if wake in ready:
                return
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
                for reply in self._feed(data):
                    with contextlib.suppress(OSError):  # client not reading: drop it
                        os.write(master, reply)
            finally:
                self._busy = False

    def _feed(self, data: bytes) -> list[bytes]:
        now = self._clock.now()
        replies: list[bytes] = []
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
                reply = self._handle(label, payload, now)
                if reply is not None:
                    replies.append(reply)
        return replies

    def _reject(self, kind: str, drop: int) -> None:
        self._errors[kind] += 1
        del self._buf[:drop]
        self._skipping = True  # bytes up to the next 0x7E belong to the bad frame

    def _handle(self, label: int, payload: bytes, now: float) -> bytes | None:
        n = len(payload)
        if label == 6:
            if not 25 <= n <= 513:
                self._errors["length"] += 1
                return None
            self._received[6] = self._received.get(6, 0) + 1
            if payload[0] != 0:
                self._errors["start_code"] += 1
                return None
            self._hold(payload[1:], now)
            return None
        if label == 3:
            if n != 2:
                self._errors["length"] += 1
                return None
            self._received[3] = self._received.get(3, 0) + 1
            user_size = payload[0] | payload[1] << 8
            fw = self._firmware
            data = bytes(
                (fw & 0xFF, fw >> 8, self._break_units, self._mab_units, self._rate_hz)
            ) + bytes(min(user_size, 508))
            return _frame(3, data)
        if label == 10:
            if n != 0:
                self._errors["length"] += 1
                return None
            self._received[10] = self._received.get(10, 0) + 1
            digits = f"{self._serial_number:08d}"
            bcd = bytes(int(digits[i : i + 2], 16) for i in range(6, -1, -2))
            return _frame(10, bcd)
        self._errors["label"] += 1
        return None

    def _hold(self, levels: bytes, now: float) -> None:
        period = 1.0 / self._rate_hz
        k = math.ceil((now - self._t0) / period - 1e-9)
        start = self._t0 + max(k, 0) * period
        active = start + self.sim_frame_time_s(len(levels))
        if self._history and self._history[-1].output_start_s >= start:
            self._history[-1] = replace(self._history[-1], dropped=True)
        self._history.append(SimDmxState(levels, now, start, active))


def _frame(label: int, data: bytes) -> bytes:
    n = len(data)
    return bytes((_START, label, n & 0xFF, n >> 8)) + data + bytes((_END,))


def serve_dmx_forever(
    *,
    serial_number: int = 12345678,
    refresh_rate_hz: int = 40,
    time_scale: float = 1.0,
    out: TextIO | None = None,
    err: TextIO | None = None,
) -> int:
    """Run one simulated widget until SIGINT/SIGTERM; print its device path first.

    The path is the first line of ``out`` (stdout), flushed at once so a parent process can
    read it; a summary of malformed frames goes to ``err`` (stderr) on exit. Must run in the
    main thread. Returns the exit code (0).
    """
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    sigs = {signal.SIGINT, signal.SIGTERM}
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)  # the sim thread inherits it
    try:
        sim = SimDmxWidget(
            clock=SimClock(time_scale), serial_number=serial_number, refresh_rate_hz=refresh_rate_hz
        )
        with sim:
            print(sim.path, file=out, flush=True)
            signal.sigwait(sigs)
        errors = {k: v for k, v in sim.sim_errors().items() if v}
        received = sum(sim.sim_received().values())
        print(f"sim dmx: {received} frames received, malformed/ignored: {errors or 'none'}",
              file=err, flush=True)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)
    return 0
