"""One table from dynamixel_sdk's native codes to words and typed gonio errors.

Three kinds of codes come back from a Dynamixel bus:

- ``COMM_*`` results of the SDK (the transfer itself: timeout, corrupt packet, busy port);
- the error number in a status packet's error byte (the servo refused the instruction);
- Hardware Error Status bits (address 70; the servo protects itself), announced by the Alert
  bit (0x80) of every status packet.

Everything that turns one of them into a message or an exception goes through this module.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from dynamixel_sdk import (
    COMM_NOT_AVAILABLE,
    COMM_PORT_BUSY,
    COMM_RX_CORRUPT,
    COMM_RX_FAIL,
    COMM_RX_TIMEOUT,
    COMM_RX_WAITING,
    COMM_SUCCESS,
    COMM_TX_ERROR,
    COMM_TX_FAIL,
)

from drivers.errors import CollisionError, CommunicationError, HardwareError

ALERT_BIT = 0x80
ERRNUM_CRC = 3

#: SDK result → (constant name, what it means).
COMM_RESULTS: dict[int, tuple[str, str]] = {
    COMM_SUCCESS: ("COMM_SUCCESS", "success"),
    COMM_PORT_BUSY: ("COMM_PORT_BUSY", "the port was still marked busy by an earlier transfer"),
    COMM_TX_FAIL: ("COMM_TX_FAIL", "the instruction packet could not be written to the port"),
    COMM_RX_FAIL: ("COMM_RX_FAIL", "no status packet could be read from the port"),
    COMM_TX_ERROR: ("COMM_TX_ERROR", "the instruction packet was malformed"),
    COMM_RX_WAITING: ("COMM_RX_WAITING", "a status packet was still arriving"),
    COMM_RX_TIMEOUT: ("COMM_RX_TIMEOUT", "no status packet arrived (the servo is silent)"),
    COMM_RX_CORRUPT: ("COMM_RX_CORRUPT", "the status packet was corrupt (bad CRC or cut short)"),
    COMM_NOT_AVAILABLE: ("COMM_NOT_AVAILABLE", "the instruction is not available"),
}
#: Results worth retrying (the bus hiccuped; the servo may be fine).
RETRYABLE_RESULTS = frozenset(
    {COMM_PORT_BUSY, COMM_TX_FAIL, COMM_RX_FAIL, COMM_RX_WAITING, COMM_RX_TIMEOUT, COMM_RX_CORRUPT}
)

#: Status-packet error number → (name, cause and fix).
PACKET_ERRORS: dict[int, tuple[str, str]] = {
    1: ("result fail", "the servo could not run the instruction (torque cannot be enabled while "
                       "a hardware error is latched: reboot the servo first)"),
    2: ("instruction error", "the servo does not know the instruction (or ACTION without "
                             "REG_WRITE)"),
    3: ("CRC error", "the servo received a corrupted packet (check cable and termination)"),
    4: ("data range error", "the value is outside the item's range"),
    5: ("data length error", "the write does not cover whole control-table items"),
    6: ("data limit error", "the value exceeds the servo's configured limit"),
    7: ("access error", "read-only or unknown address, or an EEPROM item written while torque "
                        "is on (turn torque off first)"),
}


class ServoSilentError(CommunicationError):
    """A servo did not answer (or answered garbage) after the bounded retries."""


class ServoCommandError(CommunicationError):
    """A servo answered but refused the instruction (status-packet error number)."""


class ServoHardwareError(HardwareError):
    """A servo latched a Hardware Error Status bit; ``bits`` holds the whole status byte."""

    def __init__(self, message: str, *, servo_id: int | None = None, axis: str | None = None,
                 bits: int = 0) -> None:
        super().__init__(message)
        self.servo_id, self.axis, self.bits = servo_id, axis, bits


class OverloadError(ServoHardwareError):
    """Bit 5: the load exceeded the motor's capacity (blocked arm, collision)."""


class OverheatingError(ServoHardwareError):
    """Bit 2: the winding reached the Temperature Limit."""


class ElectricalShockError(ServoHardwareError):
    """Bit 4: electrical shock on the circuit, or insufficient power."""


class EncoderError(ServoHardwareError):
    """Bit 3: the motor encoder malfunctions."""


class InputVoltageError(ServoHardwareError):
    """Bit 0: the supply voltage is outside the voltage limits."""


class TorqueOffError(HardwareError):
    """A move was asked of a servo whose torque is off."""


class MotionTimeoutError(HardwareError):
    """A move did not reach its target within the timeout (the axes were stopped)."""


class PartialMoveError(CollisionError):
    """Some goals of a sync write never arrived, the other axes moved alone, and from where
    every axis stopped the guard refuses the rest of the move as it was: re-plan from
    ``readback`` (``acquisition.devices.servos.routed_move`` routes from there)."""

    def __init__(self, message: str, readback: Mapping[str, float], lost: Sequence[str]) -> None:
        super().__init__(message)
        self.readback = dict(readback)
        """Where every axis stands (deg, read back after the stop)."""
        self.lost = tuple(lost)
        """The axes whose goal never arrived."""


@dataclass(frozen=True)
class HardwareBit:
    """One Hardware Error Status bit: mask, name, exception type, operator's next step."""

    mask: int
    name: str
    error: type[ServoHardwareError]
    next_step: str


#: Most serious first: the first matching bit names the exception.
HARDWARE_BITS: tuple[HardwareBit, ...] = (
    HardwareBit(0x20, "overload", OverloadError,
                "clear the obstruction or lighten the load, then run `gonio reboot {axis}`"),
    HardwareBit(0x04, "overheating", OverheatingError,
                "let the servo cool down and reduce its duty, then run `gonio reboot {axis}`"),
    HardwareBit(0x10, "electrical shock", ElectricalShockError,
                "check the power supply and wiring, then run `gonio reboot {axis}`"),
    HardwareBit(0x08, "motor encoder", EncoderError,
                "power-cycle the servo; replace it if the error comes back"),
    HardwareBit(0x01, "input voltage", InputVoltageError,
                "check the supply voltage against the servo's voltage limits, then run "
                "`gonio reboot {axis}`"),
)


def comm_text(result: int) -> str:
    """``"COMM_RX_TIMEOUT (no status packet arrived ...)"`` for an SDK result code."""
    name, meaning = COMM_RESULTS.get(result, (f"COMM {result}", "unknown SDK result"))
    return f"{name} ({meaning})"


def packet_error_text(error: int) -> str:
    """Words for a status packet's error byte (error number; Alert noted)."""
    number = error & ~ALERT_BIT
    name, meaning = PACKET_ERRORS.get(number, (f"error {number}", "unknown error number"))
    alert = "; Alert bit set (hardware error latched)" if error & ALERT_BIT else ""
    return f"{name}: {meaning}{alert}"


def hardware_error(bits: int, who: str, *, servo_id: int | None = None,
                   axis: str | None = None, detail: str = "",
                   shutdown: int = 0x34) -> ServoHardwareError:
    """The typed error for Hardware Error Status ``bits`` (non-zero).

    Parameters
    ----------
    who:
        How to name the servo in the message, e.g. ``"axis 'theta_i' (servo 2 on bus 'arms',
        /dev/ttyUSB0)"``.
    axis:
        Axis name used in the next step (``gonio reboot AXIS``); the servo ID if None.
    detail:
        Extra facts for the message (temperature, voltage).
    shutdown:
        The servo's Shutdown register (63): bits that turn its torque off.
    """
    matched = [b for b in HARDWARE_BITS if bits & b.mask]
    first = matched[0] if matched else None
    names = ", ".join(f"{b.name} (bit {b.mask.bit_length() - 1})" for b in matched) or (
        f"unknown bits 0x{bits:02X}")
    step = (first.next_step if first else "power-cycle the servo").format(
        axis=axis if axis else (servo_id if servo_id is not None else "AXIS"))
    extra = f" [{detail}]" if detail else ""
    torque = "the servo turned its torque off; " if bits & shutdown else ""
    message = f"{who}: hardware error {names}{extra}; {torque}{step}"
    cls = first.error if first else ServoHardwareError
    return cls(message, servo_id=servo_id, axis=axis, bits=bits)
