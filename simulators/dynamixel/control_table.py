"""The X-series control table (XM430-W350, model number 1020), as the simulator stores it.

Addresses 0–63 are EEPROM (written only while torque is off), 64–147 RAM. Values are
little-endian; items marked ``signed`` are two's complement. Unlisted bytes inside the table are
reserved: they read as 0 and refuse writes (Access error). Indirect addressing (168+) is not
simulated: the table ends at address 147.
"""

from __future__ import annotations

from dataclasses import dataclass

MODEL_NUMBER = 1020  # XM430-W350
FIRMWARE_VERSION = 48
TABLE_SIZE = 148
EEPROM_END = 64  # first RAM address


@dataclass(frozen=True)
class Item:
    """One control-table item."""

    name: str
    address: int
    size: int  # bytes
    writable: bool
    default: int
    minimum: int
    maximum: int
    signed: bool = False
    allowed: tuple[int, ...] | None = None  # discrete set of valid values, if any

    @property
    def eeprom(self) -> bool:
        """True for EEPROM items (read-only while torque is on)."""
        return self.address < EEPROM_END

    def valid(self, value: int) -> bool:
        """True if ``value`` may be written to this item."""
        if self.allowed is not None:
            return value in self.allowed
        return self.minimum <= value <= self.maximum


def _rw(name, address, size, default, lo, hi, signed=False, allowed=None) -> Item:
    return Item(name, address, size, True, default, lo, hi, signed, allowed)


def _ro(name, address, size, default=0, signed=False) -> Item:
    return Item(name, address, size, False, default, 0, 0, signed)


ITEMS: tuple[Item, ...] = (
    # EEPROM
    _ro("model_number", 0, 2, MODEL_NUMBER),
    _ro("model_information", 2, 4),
    _ro("firmware_version", 6, 1, FIRMWARE_VERSION),
    _rw("id", 7, 1, 1, 0, 252),
    _rw("baud_rate", 8, 1, 1, 0, 7),
    _rw("return_delay_time", 9, 1, 250, 0, 254),  # unit 2 µs
    _rw("drive_mode", 10, 1, 0, 0, 13),  # bit 0 reverse, bit 2 time-based profile
    _rw("operating_mode", 11, 1, 3, 0, 16, allowed=(0, 1, 3, 4, 5, 16)),
    _rw("secondary_id", 12, 1, 255, 0, 255),
    _rw("protocol_type", 13, 1, 2, 1, 2),
    _rw("homing_offset", 20, 4, 0, -1044479, 1044479, signed=True),  # ticks
    _rw("moving_threshold", 24, 4, 10, 0, 1023),  # unit 0.229 rev/min
    _rw("temperature_limit", 31, 1, 80, 0, 100),  # °C
    _rw("max_voltage_limit", 32, 2, 160, 95, 160),  # unit 0.1 V
    _rw("min_voltage_limit", 34, 2, 95, 95, 160),
    _rw("pwm_limit", 36, 2, 885, 0, 885),
    _rw("current_limit", 38, 2, 1193, 0, 1193),
    _rw("velocity_limit", 44, 4, 200, 0, 1023),  # unit 0.229 rev/min
    _rw("max_position_limit", 48, 4, 4095, 0, 4095),  # ticks
    _rw("min_position_limit", 52, 4, 0, 0, 4095),
    _rw("startup_configuration", 60, 1, 0, 0, 3),
    _rw("shutdown", 63, 1, 52, 0, 255),  # hardware-error bits that turn torque off
    # RAM
    _rw("torque_enable", 64, 1, 0, 0, 1),
    _rw("led", 65, 1, 0, 0, 1),
    _rw("status_return_level", 68, 1, 2, 0, 2),
    _ro("registered_instruction", 69, 1),
    _ro("hardware_error_status", 70, 1),
    _rw("velocity_i_gain", 76, 2, 1920, 0, 16383),
    _rw("velocity_p_gain", 78, 2, 100, 0, 16383),
    _rw("position_d_gain", 80, 2, 0, 0, 16383),
    _rw("position_i_gain", 82, 2, 0, 0, 16383),
    _rw("position_p_gain", 84, 2, 800, 0, 16383),
    _rw("feedforward_2nd_gain", 88, 2, 0, 0, 16383),
    _rw("feedforward_1st_gain", 90, 2, 0, 0, 16383),
    _rw("bus_watchdog", 98, 1, 0, 0, 127),
    _rw("goal_pwm", 100, 2, 885, -885, 885, signed=True),
    _rw("goal_current", 102, 2, 1193, -1193, 1193, signed=True),
    _rw("goal_velocity", 104, 4, 0, -1023, 1023, signed=True),
    _rw("profile_acceleration", 108, 4, 0, 0, 32767),  # unit 214.577 rev/min²
    _rw("profile_velocity", 112, 4, 0, 0, 32767),  # unit 0.229 rev/min
    _rw("goal_position", 116, 4, 0, -1048575, 1048575, signed=True),  # ticks
    _ro("realtime_tick", 120, 2),  # ms, wraps at 32768
    _ro("moving", 122, 1),
    _ro("moving_status", 123, 1),
    _ro("present_pwm", 124, 2, signed=True),
    _ro("present_current", 126, 2, signed=True),
    _ro("present_velocity", 128, 4, signed=True),  # unit 0.229 rev/min
    _ro("present_position", 132, 4, signed=True),  # ticks
    _ro("velocity_trajectory", 136, 4, signed=True),
    _ro("position_trajectory", 140, 4, signed=True),
    _ro("present_input_voltage", 144, 2, 120),  # unit 0.1 V
    _ro("present_temperature", 146, 1, 30),  # °C
    _ro("backup_ready", 147, 1),
)

BY_NAME: dict[str, Item] = {item.name: item for item in ITEMS}
BY_ADDRESS: dict[int, Item] = {item.address: item for item in ITEMS}
#: For every table address, the item covering it (None for reserved bytes).
OWNER: tuple[Item | None, ...] = tuple(
    next((it for it in ITEMS if it.address <= a < it.address + it.size), None)
    for a in range(TABLE_SIZE)
)

# Hardware error status bits (address 70).
HW_INPUT_VOLTAGE = 0x01
HW_OVERHEATING = 0x04
HW_ENCODER = 0x08
HW_ELECTRICAL_SHOCK = 0x10
HW_OVERLOAD = 0x20

# Units.
VELOCITY_UNIT_RPM = 0.229
ACCELERATION_UNIT_RPM2 = 214.577
TICKS_PER_REV = 4096
BAUD_RATES: dict[int, int] = {
    0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000,
    7: 4_500_000,
}
#: Items kept by FACTORY_RESET option 0x01 (ID) and 0x02 (ID and baud rate).
FACTORY_RESET_KEEP = {0xFF: (), 0x01: ("id",), 0x02: ("id", "baud_rate")}


def default_memory(servo_id: int, baud_index: int = 1) -> bytearray:
    """A fresh control table with factory defaults, the given ID and baud-rate index."""
    mem = bytearray(TABLE_SIZE)
    for item in ITEMS:
        mem[item.address : item.address + item.size] = encode(item, item.default)
    mem[7] = servo_id
    mem[8] = baud_index
    return mem


def encode(item: Item, value: int) -> bytes:
    """``value`` as the item's little-endian bytes."""
    return (value & ((1 << (8 * item.size)) - 1)).to_bytes(item.size, "little")


def decode(item: Item, raw: bytes | bytearray) -> int:
    """The item's value from its bytes."""
    return int.from_bytes(raw, "little", signed=item.signed)
