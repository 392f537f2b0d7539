"""DMX512 output through an Enttec DMX USB Pro compatible widget, over pyserial.

Wire format (host ↔ widget, DMX USB Pro API 1.44): every message is one frame
``0x7E, label, length LSB, length MSB, data[length], 0xE7`` with ``0 ≤ length ≤ 600``.
The labels used here:

* 6 "Output Only Send DMX Packet": data = start code (0 for dimmer data) + 24…512 channel
  levels (length 25…513). The widget keeps re-sending the last universe at its output rate.
* 3 "Get Widget Parameters": request = 2-byte user-config size (LSB first); reply = firmware
  version (LSB, MSB), break time and mark-after-break time (units of 10.67 µs), output rate
  (packets/s, 1–40; 0 = as fast as the line allows), then the user-config bytes.
* 10 "Get Widget Serial Number": empty request; reply = 4 BCD bytes, least significant first.

DMX timing (why there is a refresh limit): DMX512 runs at 250 kbaud with 11 bits per slot
(start, 8 data, 2 stop), so a slot takes 44 µs. A frame is break + mark-after-break + the
start-code slot + one slot per channel: with the widget's default break (9 × 10.67 µs) and MAB
(1 × 10.67 µs), a full universe is 96 µs + 10.7 µs + 513 × 44 µs ≈ 22.68 ms, i.e. at most
≈ 44 frames/s. The widget outputs frames at its own rate (default 40/s → one every 25 ms);
a universe handed to it while a frame is on the wire waits for the next one, and a universe
replaced before it went out is never output. :meth:`DmxWidget.send_universe` therefore spaces
sends by at least one output period, ``max(frame time, 1 / output rate)`` (for the larger of
the universe on the wire and the new one), so every state sent is output at least once, and
:meth:`DmxWidget.ready_at` bounds when it is surely on: that period (the frame in progress) +
one frame time (the frame carrying it) + a USB margin + ``settle_s`` (the fixtures' own
response). Break, MAB and output rate are the widget's own, read on open (label 3): a widget
another program configured (Set Widget Parameters, label 4; the widget keeps it through power
cycles) is paced by what it really does.

A DMX USB Pro cannot report what it outputs, so "on" is confirmed by that timing, not by a
readback. Several universes are driven by one widget each (one port per universe); the Pro
Mk2's second port needs a vendor API key and is not supported.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from enum import IntEnum
from typing import Protocol

import numpy as np
import serial

from drivers.errors import CommunicationError

START_BYTE = 0x7E
"""First byte of every frame."""
END_BYTE = 0xE7
"""Last byte of every frame."""
MAX_DATA_LENGTH = 600
"""Largest data length the widget accepts (bytes)."""
MIN_CHANNELS = 24
"""Fewest channels the widget outputs in one DMX packet (shorter universes are zero-padded)."""
MAX_CHANNELS = 512
"""Channels in one DMX512 universe."""

SLOT_TIME_S = 11 / 250_000
"""One DMX slot on the wire: 11 bits at 250 kbaud = 44 µs."""
TIME_UNIT_S = 10.67e-6
"""Unit of the widget's break and mark-after-break times (s)."""
DEFAULT_BREAK_UNITS = 9
"""Widget default break time (× 10.67 µs = 96 µs)."""
DEFAULT_MAB_UNITS = 1
"""Widget default mark-after-break time (× 10.67 µs)."""
DEFAULT_REFRESH_RATE_HZ = 40
"""Widget default DMX output rate (packets/s)."""
USB_MARGIN_S = 0.002
"""Allowance for the USB transfer from host to widget in :meth:`DmxWidget.ready_at` (s)."""


class Label(IntEnum):
    """Message labels of the DMX USB Pro API."""

    REPROGRAM_FIRMWARE = 1
    PROGRAM_FLASH_PAGE = 2
    GET_WIDGET_PARAMETERS = 3
    SET_WIDGET_PARAMETERS = 4
    RECEIVED_DMX = 5
    SEND_DMX = 6
    SEND_RDM = 7
    RECEIVE_DMX_ON_CHANGE = 8
    RECEIVED_DMX_CHANGE_OF_STATE = 9
    GET_SERIAL_NUMBER = 10
    SEND_RDM_DISCOVERY = 11


class Clock(Protocol):
    """Time source for pacing: seconds from :meth:`now`, blocking :meth:`sleep` (s)."""

    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """The host's monotonic clock (default for real hardware)."""

    def now(self) -> float:
        """Host monotonic time (s)."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` (s); non-positive values return at once."""
        if seconds > 0:
            time.sleep(seconds)


# --------------------------------------------------------------------------------------------
# Frame codec
# --------------------------------------------------------------------------------------------


def encode_frame(label: int, data: bytes = b"") -> bytes:
    """One widget frame: ``0x7E, label, len LSB, len MSB, data, 0xE7``.

    Raises
    ------
    ValueError
        If the label is not a byte or the data is longer than 600 bytes.
    """
    if not 0 <= label <= 255:
        raise ValueError(f"DMX widget label {label} is not a byte")
    n = len(data)
    if n > MAX_DATA_LENGTH:
        raise ValueError(f"DMX widget frame data of {n} bytes exceeds {MAX_DATA_LENGTH}")
    return bytes((START_BYTE, label, n & 0xFF, n >> 8)) + bytes(data) + bytes((END_BYTE,))


def decode_frame(frame: bytes) -> tuple[int, bytes]:
    """``(label, data)`` of exactly one complete frame; strict about every byte.

    Raises
    ------
    ValueError
        On a wrong start or end byte, or a length that disagrees with the frame's size.
    """
    if len(frame) < 5 or frame[0] != START_BYTE:
        raise ValueError("DMX widget frame does not start with 0x7E")
    n = frame[2] | frame[3] << 8
    if n > MAX_DATA_LENGTH or len(frame) != n + 5:
        raise ValueError(f"DMX widget frame length field {n} disagrees with {len(frame)} bytes")
    if frame[-1] != END_BYTE:
        raise ValueError(f"DMX widget frame ends with 0x{frame[-1]:02X}, not 0xE7")
    return frame[1], bytes(frame[4:-1])


class FrameReader:
    """Incremental decoder for the widget's replies; skips bytes that do not form a frame."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Add received bytes; return the ``(label, data)`` of every frame now complete."""
        self._buf += data
        frames: list[tuple[int, bytes]] = []
        buf = self._buf
        while buf:
            if buf[0] != START_BYTE:
                i = buf.find(START_BYTE)
                del buf[: len(buf) if i < 0 else i]
                continue
            if len(buf) < 4:
                break
            n = buf[2] | buf[3] << 8
            if n > MAX_DATA_LENGTH:
                del buf[0]
                continue
            if len(buf) < n + 5:
                break
            if buf[n + 4] != END_BYTE:
                del buf[0]
                continue
            frames.append((buf[1], bytes(buf[4 : n + 4])))
            del buf[: n + 5]
        return frames


def _as_levels(levels: bytes | bytearray | Sequence[int] | np.ndarray) -> bytes:
    if isinstance(levels, bytes | bytearray | memoryview):
        out = bytes(levels)
    else:
        arr = np.asarray(levels)
        if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
            raise ValueError("DMX levels must be a 1-D sequence of integers 0–255")
        if arr.size and (arr.min() < 0 or arr.max() > 255):
            raise ValueError(f"DMX levels must lie in 0–255, got {arr.min()}…{arr.max()}")
        out = arr.astype(np.uint8).tobytes()
    if len(out) > MAX_CHANNELS:
        raise ValueError(f"a DMX universe has {MAX_CHANNELS} channels, got {len(out)} levels")
    return out


def encode_dmx_packet(
    levels: bytes | bytearray | Sequence[int] | np.ndarray, *, start_code: int = 0
) -> bytes:
    """Label-6 frame sending ``levels`` (channel 1 first), zero-padded to 24 channels."""
    data = _as_levels(levels).ljust(MIN_CHANNELS, b"\0")
    return encode_frame(Label.SEND_DMX, bytes((start_code,)) + data)


def frame_time_s(
    n_channels: int,
    *,
    break_units: int = DEFAULT_BREAK_UNITS,
    mab_units: int = DEFAULT_MAB_UNITS,
) -> float:
    """Time one DMX frame of ``n_channels`` (padded to ≥ 24) takes on the wire (s)."""
    slots = 1 + max(MIN_CHANNELS, n_channels)
    return (break_units + mab_units) * TIME_UNIT_S + slots * SLOT_TIME_S


@dataclass(frozen=True)
class WidgetParameters:
    """Reply to Get Widget Parameters (label 3).

    Attributes
    ----------
    firmware_version:
        16-bit version; the MSB is the firmware variety (1 = DMX, 2 = RDM, 3 = RDM sniffer).
    break_units, mab_units:
        Break and mark-after-break times in units of 10.67 µs.
    refresh_rate_hz:
        DMX output rate (packets/s); 0 means as fast as the line allows.
    user_config:
        The user configuration bytes that were asked for.
    """

    firmware_version: int
    break_units: int
    mab_units: int
    refresh_rate_hz: int
    user_config: bytes = b""

    @property
    def break_s(self) -> float:
        """Break time (s)."""
        return self.break_units * TIME_UNIT_S

    @property
    def mab_s(self) -> float:
        """Mark-after-break time (s)."""
        return self.mab_units * TIME_UNIT_S

    @classmethod
    def from_reply(cls, data: bytes) -> WidgetParameters:
        """Decode a label-3 reply's data; ``ValueError`` if shorter than 5 bytes."""
        if len(data) < 5:
            raise ValueError(f"Get Widget Parameters reply of {len(data)} bytes, expected ≥ 5")
        return cls(data[0] | data[1] << 8, data[2], data[3], data[4], bytes(data[5:]))

    def to_reply(self) -> bytes:
        """The label-3 reply data for these parameters."""
        v = self.firmware_version
        fields = (v & 0xFF, v >> 8, self.break_units, self.mab_units, self.refresh_rate_hz)
        return bytes(fields) + self.user_config


def decode_serial_number(data: bytes) -> str:
    """The 8-digit serial number from a label-10 reply (4 BCD bytes, LSB first)."""
    if len(data) != 4:
        raise ValueError(f"serial number reply of {len(data)} bytes, expected 4")
    digits = "".join(f"{b:02X}" for b in reversed(data))
    if not digits.isdigit():
        raise ValueError(f"serial number reply {data.hex()} is not BCD")
    return digits


# --------------------------------------------------------------------------------------------
# Widget driver
# --------------------------------------------------------------------------------------------


class DmxWidget:
    """One Enttec DMX USB Pro compatible widget driving one DMX universe.

    Opens the port on construction (``serial.serial_for_url``, so ``spy:///dev/ttyUSB0`` dumps
    the traffic and a plain pty path works) and, with ``probe``, asks the widget for its
    parameters so pacing uses its real break, MAB and output rate.

    Parameters
    ----------
    port:
        Device path or pyserial URL.
    timeout_s:
        How long to wait for a reply (s).
    write_timeout_s:
        How long a write may block before the widget counts as gone (s).
    settle_s:
        Time the fixtures on this line need after their frame arrived before their light is
        steady (LED driver slew, dimming filter) (s).
    clock:
        Time source for pacing and timestamps; host monotonic time by default.
    probe:
        Ask for the widget parameters on open (raises if nothing answers).

    Raises
    ------
    CommunicationError
        If the port cannot be opened or (with ``probe``) the widget does not answer.
    """

    def __init__(
        self,
        port: str,
        *,
        timeout_s: float = 0.5,
        write_timeout_s: float = 1.0,
        settle_s: float = 0.0,
        clock: Clock | None = None,
        probe: bool = True,
    ) -> None:
        if settle_s < 0:
            raise ValueError(f"settle_s must be ≥ 0, got {settle_s}")
        self._port = port
        self._timeout_s = float(timeout_s)
        self.settle_s = float(settle_s)
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self._reader = FrameReader()
        self._params = WidgetParameters(
            0, DEFAULT_BREAK_UNITS, DEFAULT_MAB_UNITS, DEFAULT_REFRESH_RATE_HZ
        )
        self._last_sent_s: float | None = None
        self._last_channels = MAX_CHANNELS
        # size of the universe the widget was outputting when the last one was sent (unknown,
        # so a full universe, before this driver's first send: another client's, say)
        self._prior_channels = MAX_CHANNELS
        try:
            self._serial = serial.serial_for_url(
                port,
                baudrate=115200,  # a dummy on the widget's virtual COM port
                timeout=self._timeout_s,
                write_timeout=write_timeout_s,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise CommunicationError(
                f"cannot open DMX widget port {port} ({_one_line(exc)}); check the path, "
                "the USB cable and that no other program holds the port"
            ) from None
        if probe:
            try:
                self.get_parameters()
            except BaseException:
                self.close()
                raise

    # -- lifecycle -----------------------------------------------------------------------------

    @property
    def port(self) -> str:
        """The port or URL this widget was opened on."""
        return self._port

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._serial is not None and self._serial.is_open

    def close(self) -> None:
        """Close the port (idempotent; the widget keeps outputting its last universe)."""
        ser, self._serial = self._serial, None
        if ser is not None:
            with suppress(serial.SerialException, OSError):
                ser.close()

    def __enter__(self) -> DmxWidget:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"DmxWidget({self._port!r})"

    # -- timing --------------------------------------------------------------------------------

    @property
    def parameters(self) -> WidgetParameters:
        """The last parameters read from the widget (defaults until read)."""
        return self._params

    def frame_time_s(self, n_channels: int | None = None) -> float:
        """Wire time of one frame of ``n_channels`` (default: the last size sent) (s)."""
        n = self._last_channels if n_channels is None else n_channels
        p = self._params
        return frame_time_s(n, break_units=p.break_units, mab_units=p.mab_units)

    def frame_period_s(self, n_channels: int | None = None) -> float:
        """Shortest spacing between sends so every universe is output: the output period (s)."""
        rate = self._params.refresh_rate_hz
        wire = self.frame_time_s(n_channels)
        return max(wire, 1.0 / rate) if rate > 0 else wire

    def ready_at(self, sent_at_s: float, n_channels: int | None = None) -> float:
        """Clock time by which a universe sent at ``sent_at_s`` is surely on and settled (s).

        One output period of the frame in progress + one frame time (the frame carrying the
        new levels) + :data:`USB_MARGIN_S` + :attr:`settle_s`. The frame in progress is sized
        by the larger of this universe and the one before it when ``sent_at_s`` is the last
        send, else by a full universe (the worst case).
        """
        n = self._last_channels if n_channels is None else n_channels
        prior = self._prior_channels if sent_at_s == self._last_sent_s else MAX_CHANNELS
        return (
            sent_at_s
            + self.frame_period_s(max(n, prior))
            + self.frame_time_s(n)
            + USB_MARGIN_S
            + self.settle_s
        )

    # -- commands ------------------------------------------------------------------------------

    def send_universe(self, levels: bytes | bytearray | Sequence[int] | np.ndarray) -> float:
        """Output ``levels`` (channel 1 first, ≤ 512 values 0–255), respecting the refresh limit.

        Blocks until one output period has passed since the previous send, then hands the
        universe to the widget. Returns the clock time it was handed over (s); the light is
        surely on at :meth:`ready_at` of that time.

        Raises
        ------
        ValueError
            If the levels are not ≤ 512 integers 0–255 (nothing is sent).
        CommunicationError
            If the widget is gone (unplugged, powered off).
        """
        frame = encode_dmx_packet(levels)
        n = len(frame) - 6
        if self._last_sent_s is not None:
            # the previous universe's frame starts within the period of the frame it waited for
            period = self.frame_period_s(max(self._last_channels, self._prior_channels))
            self._clock.sleep(self._last_sent_s + period - self._clock.now())
        with self._io("sending a DMX universe"):
            self._ser().write(frame)
        self._last_sent_s = self._clock.now()
        self._prior_channels, self._last_channels = self._last_channels, n
        return self._last_sent_s

    def get_parameters(self, user_config_size: int = 0) -> WidgetParameters:
        """Ask the widget for its firmware version, break, MAB and output rate (label 3)."""
        if not 0 <= user_config_size <= 508:
            raise ValueError(f"user_config_size must be 0–508, got {user_config_size}")
        size = bytes((user_config_size & 0xFF, user_config_size >> 8))
        data = self._request(Label.GET_WIDGET_PARAMETERS, size, "Get Widget Parameters")
        try:
            self._params = WidgetParameters.from_reply(data)
        except ValueError as exc:
            raise self._malformed(exc) from None
        return self._params

    def get_serial_number(self) -> str:
        """The widget's serial number as printed on its case (label 10).

        The widget stops its DMX output on this request (any request but labels 3 and 6 turns
        its port to input; fixtures keep their last levels); the next :meth:`send_universe`
        restarts it.
        """
        data = self._request(Label.GET_SERIAL_NUMBER, b"", "Get Widget Serial Number")
        try:
            return decode_serial_number(data)
        except ValueError as exc:
            raise self._malformed(exc) from None

    # -- internals -----------------------------------------------------------------------------

    def _malformed(self, exc: ValueError) -> CommunicationError:
        return CommunicationError(
            f"DMX widget on {self._port} sent a malformed reply ({exc}); "
            "check that it is an Enttec DMX USB Pro compatible widget"
        )

    def _ser(self) -> serial.SerialBase:
        if self._serial is None:
            raise CommunicationError(
                f"DMX widget port {self._port} is closed; open a new DmxWidget to reconnect"
            )
        return self._serial

    @contextmanager
    def _io(self, action: str) -> Iterator[None]:
        try:
            yield
        except (serial.SerialException, OSError) as exc:
            if isinstance(exc, CommunicationError):
                raise
            self.close()
            raise CommunicationError(
                f"DMX widget on {self._port} stopped responding while {action} "
                f"({_one_line(exc)}); check its USB cable and power, then reconnect"
            ) from None

    def _request(self, label: int, payload: bytes, what: str) -> bytes:
        ser = self._ser()
        with self._io(f"asking {what}"):
            ser.reset_input_buffer()
            self._reader = FrameReader()
            ser.write(encode_frame(label, payload))
            deadline = time.monotonic() + self._timeout_s
            try:
                while (remaining := deadline - time.monotonic()) > 0:
                    ser.timeout = remaining
                    chunk = ser.read(max(1, ser.in_waiting))
                    for got, data in self._reader.feed(chunk):
                        if got == label:
                            return data
            finally:
                ser.timeout = self._timeout_s
        raise CommunicationError(
            f"no reply to {what} from {self._port} within {self._timeout_s:g} s; check that "
            "it is an Enttec DMX USB Pro compatible widget and that its USB cable is plugged in"
        )


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__
