"""Dynamixel Protocol 2.0 framing: CRC-16, byte stuffing, instruction and status packets.

A packet on the wire is ``FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAMS... | CRC_L CRC_H``.
``LEN`` counts the (stuffed) instruction, parameters and the two CRC bytes. A status packet is a
packet with instruction ``0x55`` whose first parameter is the error byte. Inside the
instruction/parameter region every ``FF FF FD`` is sent as ``FF FF FD FD`` (byte stuffing), so
the header never appears inside a packet. The CRC is CRC-16 with polynomial 0x8005, initial
value 0, no reflection, over everything from the header to the last (stuffed) parameter byte.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
ALERT_BIT = 0x80
#: Largest LEN field accepted when parsing (the SDK's own buffer is 1 KiB).
MAX_LENGTH = 1024


class Instruction(IntEnum):
    """Instruction codes of Protocol 2.0."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorCode(IntEnum):
    """Error numbers carried in the low 7 bits of a status packet's error byte."""

    NONE = 0x00
    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07


def _make_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 of Protocol 2.0 (polynomial 0x8005, init 0, not reflected) over ``data``."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(region: bytes | bytearray) -> bytes:
    """Byte-stuff the instruction/parameter region: every ``FF FF FD`` becomes ``FF FF FD FD``."""
    out = bytearray()
    for byte in region:
        out.append(byte)
        if byte == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(region: bytes | bytearray) -> bytes:
    """Undo :func:`stuff`: drop the ``FD`` that follows each ``FF FF FD``."""
    out = bytearray()
    i, n = 0, len(region)
    while i < n:
        byte = region[i]
        out.append(byte)
        i += 1
        stuffed = byte == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF
        if stuffed and i < n and region[i] == 0xFD:
            i += 1
    return bytes(out)


def build_packet(servo_id: int, instruction: int, params: bytes | bytearray = b"") -> bytes:
    """Frame one packet: header, ID, length, stuffed instruction + params, CRC.

    Parameters
    ----------
    servo_id:
        0–252, or 254 (broadcast).
    instruction:
        Instruction code (``0x55`` for a status packet).
    params:
        Unstuffed parameter bytes (for a status packet: error byte first).
    """
    if not 0 <= servo_id <= 0xFE:
        raise ValueError(f"servo ID must be 0..254, got {servo_id}")
    region = stuff(bytes([instruction]) + bytes(params))
    length = len(region) + 2
    body = HEADER + bytes([servo_id, length & 0xFF, length >> 8]) + region
    crc = crc16(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def build_status(servo_id: int, error: int = 0, params: bytes | bytearray = b"") -> bytes:
    """Frame a status packet (instruction 0x55) with ``error`` and unstuffed ``params``."""
    return build_packet(servo_id, Instruction.STATUS, bytes([error & 0xFF]) + bytes(params))


@dataclass(frozen=True)
class Packet:
    """One parsed packet (parameters already unstuffed).

    ``crc_ok`` is False when the received CRC does not match; the other fields are then
    best-effort (the ID is usually right, which is what a servo needs to answer with a CRC error).
    """

    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool = True

    @property
    def error(self) -> int:
        """Error byte of a status packet."""
        return self.params[0] if self.params else 0

    @property
    def data(self) -> bytes:
        """Data bytes of a status packet (after the error byte)."""
        return self.params[1:]


def parse_packet(raw: bytes | bytearray) -> Packet:
    """Parse exactly one complete packet; ``ValueError`` if it is malformed or incomplete."""
    packets = list(PacketParser().feed(raw))
    if len(packets) != 1:
        raise ValueError(f"expected one complete packet, found {len(packets)} in {raw.hex(' ')}")
    return packets[0]


class PacketParser:
    """Incremental parser: feed bytes as they arrive, get complete packets back.

    Garbage before a header is skipped; a LEN field below 3 or above :data:`MAX_LENGTH` makes the
    parser resynchronise on the next header.
    """

    def __init__(self) -> None:
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a packet."""
        return len(self._buf)

    def clear(self) -> None:
        """Forget any partial packet."""
        self._buf.clear()

    def feed(self, data: bytes | bytearray) -> Iterator[Packet]:
        """Add ``data``; yield every packet it completes, in order."""
        buf = self._buf
        buf += data
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # Keep a possible partial header at the end.
                keep = 0
                for k in (3, 2, 1):
                    if buf.endswith(HEADER[:k]):
                        keep = k
                        break
                del buf[: len(buf) - keep]
                return
            if start:
                del buf[:start]
            if len(buf) < 7:
                return
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > MAX_LENGTH:
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                return
            raw = bytes(buf[:total])
            del buf[:total]
            crc_ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
            region = unstuff(raw[7:-2])
            yield Packet(raw[4], region[0], region[1:], crc_ok)


def from_le(data: bytes | bytearray, signed: bool = False) -> int:
    """Little-endian bytes to int."""
    return int.from_bytes(data, "little", signed=signed)
