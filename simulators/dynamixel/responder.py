"""Instruction handling of a bus of simulated servos: one parsed packet in, status packets out.

Pure logic, no I/O: :class:`simulators.dynamixel.bus.SimServoBus` feeds it packets from the pty
and schedules the replies (return delay, injected faults).

Rules followed (Protocol 2.0):

- A packet with a bad CRC addressed to one servo gets a status packet with the CRC error;
  broadcast packets with a bad CRC are ignored.
- Broadcast PING: every servo answers, in ID order. SYNC_READ / BULK_READ: the listed servos
  answer in list order. SYNC_WRITE, BULK_WRITE and every broadcast write-type instruction get
  no reply.
- Status Return Level: 0 answers PING only, 1 PING and reads, 2 everything.
- The error byte carries the error number, plus the Alert bit (0x80) when the servo's Hardware
  Error Status is non-zero.
- Instruction faults (drawn by the bus per addressed servo, see :meth:`Responder.addressed`): a
  servo in ``deaf`` never hears the packet; one in ``garbled`` hears it with a bad CRC (the
  unicast rule above; a broadcast is ignored by that servo while the others act on it).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence

from simulators.dynamixel import control_table as ct
from simulators.dynamixel.protocol import (
    ALERT_BIT,
    BROADCAST_ID,
    ErrorCode,
    Instruction,
    Packet,
    build_status,
    from_le,
)
from simulators.dynamixel.servo import SimServo

Reply = tuple[SimServo, bytes]
_READS = (Instruction.READ, Instruction.SYNC_READ, Instruction.BULK_READ)


def _status(servo: SimServo, error: int, data: bytes = b"", addressed_id: int | None = None,
            alert: bool | None = None) -> bytes:
    if alert is None:
        alert = servo.hardware_error != 0
    sid = servo.servo_id if addressed_id is None else addressed_id
    return build_status(sid, error | (ALERT_BIT if alert else 0), data)


def _answers(servo: SimServo, instruction: int) -> bool:
    level = servo.status_return_level
    return instruction == Instruction.PING or level >= 2 or (level == 1 and instruction in _READS)


def _ping_data(servo: SimServo) -> bytes:
    return ct.MODEL_NUMBER.to_bytes(2, "little") + bytes([ct.FIRMWARE_VERSION])


class Responder:
    """Answers packets on behalf of ``servos``.

    Parameters
    ----------
    servos:
        The servos on the bus (looked up by their present ID, so ID writes take effect).
    hears:
        Optional filter: a servo for which it returns False ignores the packet (used to model
        a baud-rate mismatch).
    """

    def __init__(self, servos: Sequence[SimServo],
                 hears: Callable[[SimServo], bool] | None = None) -> None:
        self.servos = list(servos)
        self.hears = hears
        self._missing: Collection[SimServo] = ()  # servos that miss the packet being handled

    def _listening(self) -> list[SimServo]:
        servos = self.servos
        if self._missing:
            servos = [s for s in servos if s not in self._missing]
        if self.hears is None:
            return servos
        return [s for s in servos if self.hears(s)]

    def addressed(self, pkt: Packet) -> list[SimServo]:
        """The servos ``pkt`` is meant for, in packet order: the unicast ID, the IDs a
        SYNC/BULK instruction lists, every servo for other broadcasts (deafness ignored)."""
        by_id = {s.servo_id: s for s in self.servos}
        p = pkt.params
        if pkt.servo_id != BROADCAST_ID:
            ids: list[int] = [pkt.servo_id]
        elif pkt.instruction == Instruction.SYNC_READ:
            ids = list(p[4:])
        elif pkt.instruction == Instruction.SYNC_WRITE and len(p) >= 4:
            block = 1 + from_le(p[2:4])
            ids = list(p[4::block]) if block > 1 else []
        elif pkt.instruction == Instruction.BULK_READ:
            ids = list(p[0::5])
        elif pkt.instruction == Instruction.BULK_WRITE:
            ids, i = [], 0
            while i + 5 <= len(p):
                ids.append(p[i])
                i += 5 + from_le(p[i + 3 : i + 5])
        else:
            return sorted(self.servos, key=lambda s: s.servo_id)
        return [by_id[i] for i in dict.fromkeys(ids) if i in by_id]

    def _find(self, servo_id: int) -> SimServo | None:
        for s in self._listening():
            if s.servo_id == servo_id:
                return s
        return None

    def handle(self, pkt: Packet, deaf: Collection[SimServo] = (),
               garbled: Collection[SimServo] = ()) -> list[Reply]:
        """Execute ``pkt``; return the status packets to send, in order.

        ``deaf`` servos do not hear it; ``garbled`` ones hear it with a bad CRC.
        """
        if pkt.servo_id == BROADCAST_ID:
            if not pkt.crc_ok:
                return []
            self._missing = set(deaf) | set(garbled)
            try:
                return self._broadcast(pkt)
            finally:
                self._missing = ()
        servo = self._find(pkt.servo_id)
        if servo is None or servo in deaf:
            return []
        if not pkt.crc_ok or servo in garbled:
            if servo.status_return_level < 2 and pkt.instruction != Instruction.PING:
                return []
            return [(servo, _status(servo, ErrorCode.CRC))]
        return self._unicast(servo, pkt)

    # ------------------------------------------------------------------ unicast
    def _unicast(self, servo: SimServo, pkt: Packet) -> list[Reply]:
        inst, p, sid = pkt.instruction, pkt.params, pkt.servo_id
        data = b""
        alert: bool | None = None
        if inst == Instruction.PING:
            err, data = (ErrorCode.NONE, _ping_data(servo)) if not p else (
                ErrorCode.DATA_LENGTH, b"")
        elif inst == Instruction.READ:
            if len(p) != 4:
                err = ErrorCode.DATA_LENGTH
            else:
                err, data = servo.read(from_le(p[0:2]), from_le(p[2:4]))
        elif inst == Instruction.WRITE:
            err = ErrorCode.DATA_LENGTH if len(p) < 3 else servo.write(from_le(p[0:2]), p[2:])
        elif inst == Instruction.REG_WRITE:
            err = ErrorCode.DATA_LENGTH if len(p) < 3 else servo.reg_write(from_le(p[0:2]), p[2:])
        elif inst == Instruction.ACTION:
            err = ErrorCode.DATA_LENGTH if p else servo.action()
        elif inst == Instruction.REBOOT:
            alert = servo.hardware_error != 0  # the reply goes out before the reboot
            err = ErrorCode.DATA_LENGTH if p else ErrorCode.NONE
            if not err:
                servo.reboot()
        elif inst == Instruction.FACTORY_RESET:
            err = ErrorCode.DATA_LENGTH if len(p) != 1 else servo.factory_reset(p[0])
        else:
            err = ErrorCode.INSTRUCTION  # unknown, or a broadcast-only instruction
        if not _answers(servo, inst):
            return []
        return [(servo, _status(servo, err, data if not err else b"", sid, alert))]

    # ------------------------------------------------------------------ broadcast
    def _broadcast(self, pkt: Packet) -> list[Reply]:
        inst, p = pkt.instruction, pkt.params
        listening = self._listening()
        if inst == Instruction.PING:
            if p:
                return []
            return [(s, _status(s, ErrorCode.NONE, _ping_data(s)))
                    for s in sorted(listening, key=lambda s: s.servo_id)]
        if inst == Instruction.SYNC_READ:
            return self._sync_read(p)
        if inst == Instruction.BULK_READ:
            return self._bulk_read(p)
        if inst == Instruction.SYNC_WRITE:
            self._sync_write(p)
        elif inst == Instruction.BULK_WRITE:
            self._bulk_write(p)
        elif inst == Instruction.WRITE and len(p) >= 3:
            for s in listening:
                s.write(from_le(p[0:2]), p[2:])
        elif inst == Instruction.REG_WRITE and len(p) >= 3:
            for s in listening:
                s.reg_write(from_le(p[0:2]), p[2:])
        elif inst == Instruction.ACTION and not p:
            for s in listening:
                s.action()
        elif inst == Instruction.REBOOT and not p:
            for s in listening:
                s.reboot()
        elif inst == Instruction.FACTORY_RESET and len(p) == 1:
            for s in listening:
                s.factory_reset(p[0])
        return []

    def _read_reply(self, servo: SimServo, address: int, length: int) -> list[Reply]:
        if not _answers(servo, Instruction.SYNC_READ):
            return []
        err, data = servo.read(address, length)
        return [(servo, _status(servo, err, data))]

    def _sync_read(self, p: bytes) -> list[Reply]:
        if len(p) < 5:
            return []
        address, length = from_le(p[0:2]), from_le(p[2:4])
        replies: list[Reply] = []
        for sid in p[4:]:
            servo = self._find(sid)
            if servo is not None:
                replies += self._read_reply(servo, address, length)
        return replies

    def _bulk_read(self, p: bytes) -> list[Reply]:
        if not p or len(p) % 5:
            return []
        replies: list[Reply] = []
        for i in range(0, len(p), 5):
            servo = self._find(p[i])
            if servo is not None:
                replies += self._read_reply(servo, from_le(p[i + 1 : i + 3]),
                                            from_le(p[i + 3 : i + 5]))
        return replies

    def _sync_write(self, p: bytes) -> None:
        if len(p) < 4:
            return
        address, length = from_le(p[0:2]), from_le(p[2:4])
        block = 1 + length
        body = p[4:]
        if length == 0 or not body or len(body) % block:
            return
        for i in range(0, len(body), block):
            servo = self._find(body[i])
            if servo is not None:
                servo.write(address, body[i + 1 : i + block])

    def _bulk_write(self, p: bytes) -> None:
        i = 0
        chunks: list[tuple[SimServo | None, int, bytes]] = []
        while i + 5 <= len(p):
            sid, address, length = p[i], from_le(p[i + 1 : i + 3]), from_le(p[i + 3 : i + 5])
            data = p[i + 5 : i + 5 + length]
            if len(data) != length or length == 0:
                return  # malformed: ignore the whole packet
            chunks.append((self._find(sid), address, data))
            i += 5 + length
        if i != len(p):
            return
        for servo, address, data in chunks:
            if servo is not None:
                servo.write(address, data)
