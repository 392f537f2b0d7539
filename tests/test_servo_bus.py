"""ServoBus (drivers/) over the real dynamixel_sdk, against the simulator on a pty."""

from __future__ import annotations

import time

import pytest

from drivers.dynamixel import (
    InputVoltageError,
    OverheatingError,
    OverloadError,
    ServoBus,
    ServoCommandError,
    ServoSilentError,
)
from drivers.dynamixel.latency import latency_timer_ms, latency_warning
from drivers.errors import CommunicationError, ConfigError, HardwareError
from simulators.dynamixel import SimServoBus


@pytest.fixture
def bus(sim):
    with ServoBus(sim.port, 57600, name="arms", axis_names={2: "theta_r"}) as b:
        b.set_return_delay([1, 2, 3], 0)
        yield b


def settle(bus: ServoBus, ids, timeout_s: float = 5.0) -> None:
    deadline = time.monotonic() + timeout_s
    while any(bus.read_moving(ids).values()):
        assert time.monotonic() < deadline, "servos did not settle"
        time.sleep(0.005)


# ---------------------------------------------------------------- opening
def test_missing_port_is_a_one_line_communication_error():
    with pytest.raises(CommunicationError) as info:
        ServoBus("/dev/ttyUSB_gonio_missing", name="arms").open()
    message = str(info.value)
    assert "/dev/ttyUSB_gonio_missing" in message and "arms" in message and "\n" not in message


def test_unsupported_baud_is_a_config_error(sim):
    with pytest.raises(ConfigError, match="12345"):
        ServoBus(sim.port, 12345).open()


def test_a_port_is_not_shared_by_two_buses(sim):
    with ServoBus(sim.port), pytest.raises(CommunicationError, match="already in use"):
        ServoBus(sim.port).open()


def test_closed_bus_refuses_io(sim):
    with pytest.raises(CommunicationError, match="not open"):
        ServoBus(sim.port).read_positions([1])


# ---------------------------------------------------------------- basic I/O
def test_ping_require_and_missing_ids(bus):
    assert bus.ping(1) == 1020
    assert bus.require([1, 2, 3]) == {1: 1020, 2: 1020, 3: 1020}
    bus.label(7, "phi")
    with pytest.raises(ServoSilentError) as info:
        bus.require([1, 5, 7])
    message = str(info.value)
    assert "5" in message and "7 (axis 'phi')" in message and "gonio scan" in message
    assert "\n" not in message


def test_silent_servo_names_bus_port_id_and_axis(bus, sim):
    t0 = time.perf_counter()
    with pytest.raises(ServoSilentError) as info:
        bus.read_positions([1, 2, 9])
    bus.label(9, "theta_i")
    message = str(info.value)
    assert "servo 9" in message and "arms" in message and sim.port in message
    assert time.perf_counter() - t0 < 1.0  # bounded retries
    with pytest.raises(ServoSilentError, match="axis 'theta_i'"):
        bus.ping(9)


def test_scan_finds_servos_at_their_baud_rate(clock):
    with SimServoBus([1, 4], baud=1_000_000, clock=clock, strict_baud=True) as sim, \
            ServoBus(sim.port, 57600) as bus:
        assert bus.scan(range(1, 6), bauds=(57600, 1_000_000)) == {1_000_000: {1: 1020, 4: 1020}}
        assert bus.try_ping(1) is None  # back at the bus's own baud rate
        found = bus.scan(bauds=(1_000_000,))  # all IDs: broadcast ping
        assert found == {1_000_000: {1: 1020, 4: 1020}}


def test_sync_write_then_sync_read(bus, clock):
    bus.set_torque([1, 2, 3], True)
    with bus.permit_goals():  # as the motion controller does, after its guard
        bus.write_goals({1: 1000, 2: 3000, 3: -0 + 2500})
    settle(bus, [1, 2, 3])
    assert bus.read_positions([1, 2, 3]) == {1: 1000, 2: 3000, 3: 2500}
    motion = bus.read_motion([2])[2]
    assert (motion.goal, motion.position, motion.moving, motion.velocity) == (3000, 3000, False, 0)


def test_signed_values(bus):
    bus.write(1, 20, 4, -3000)  # homing offset (torque off)
    assert bus.read_positions([1]) == {1: 2048 - 3000}
    assert bus.read(1, 20, 4) == -3000


def test_read_status(bus, sim):
    bus.set_torque([2], True)
    sim.servos[3].sim_trip(0x20)
    status = bus.read_status([1, 2, 3])
    assert status[1].torque_on is False and status[2].torque_on is True
    assert (status[2].position, status[2].goal, status[2].moving) == (2048, 2048, False)
    assert status[2].voltage_v == 12.0 and 25 <= status[2].temperature_c <= 40
    assert status[3].hardware_error == 0x20 and status[1].hardware_error == 0


def test_set_profile(bus):
    bus.set_profile(1, velocity=150, acceleration=30)
    assert bus.read(1, 108, 4) == 30 and bus.read(1, 112, 4) == 150
    with pytest.raises(ConfigError, match="40000"):
        bus.set_profile(1, velocity=40000, acceleration=0)


# ---------------------------------------------------------------- errors
def test_refused_write_names_the_error_and_fix(bus):
    bus.set_torque([1], True)
    with pytest.raises(ServoCommandError) as info:
        bus.set_return_delay([1], 0)  # EEPROM while torque is on
    assert "access error" in str(info.value) and "torque" in str(info.value)


def test_overload_is_typed_and_names_axis_bit_and_next_step(bus, sim):
    bus.set_torque([2], True)
    sim.servos[2].sim_trip(0x20)
    with pytest.raises(OverloadError) as info:
        bus.read_positions([1, 2])
    error = info.value
    assert isinstance(error, HardwareError)
    assert (error.servo_id, error.axis, error.bits) == (2, "theta_r", 0x20)
    message = str(error)
    assert "axis 'theta_r'" in message and "servo 2" in message and "bit 5" in message
    assert "gonio reboot theta_r" in message and "\n" not in message


def test_torque_on_refused_while_error_latched_then_reboot_clears(bus, sim):
    sim.servos[1].sim_trip(0x04)
    with pytest.raises(OverheatingError, match="cool"):
        bus.set_torque([1], True)
    bus.reboot(1)  # the simulated winding is cool: the latch clears
    bus.set_torque([1], True)
    assert bus.read_status([1])[1].torque_on


def test_input_voltage_error_keeps_torque(bus, sim):
    bus.set_torque([3], True)
    sim.servos[3].sim_set_supply(9.0)
    with pytest.raises(InputVoltageError) as info:
        bus.read_moving([3])
    assert "9.0 V" in str(info.value) and "turned its torque off" not in str(info.value)


def test_port_left_busy_by_an_interrupted_transfer_recovers(bus):
    bus._port.is_using = True  # what an exception inside the SDK leaves behind
    assert bus.read_positions([1]) == {1: 2048}


def test_a_dead_port_handle_is_reopened(bus):
    bus._port.ser.close()  # e.g. the adapter was unplugged and plugged back in
    assert bus.read_positions([1, 2]) == {1: 2048, 2: 2048}
    assert bus.stats["retries"] >= 1


def test_retries_hide_dropped_and_corrupt_replies(clock):
    """1,000 consecutive sync reads of 3 servos with 5 % drops and 5 % corrupt replies."""
    positions = {1: 1000, 2: 2048, 3: 3100}
    with SimServoBus([1, 2, 3], clock=clock, faults=["drop=0.05,corrupt=0.05"], seed=3,
                     positions=positions) as sim, ServoBus(sim.port) as bus:
        for servo in sim.servos.values():
            servo.mem[9] = 0
        for _ in range(1000):
            assert bus.read_positions([1, 2, 3]) == positions
        assert sim.stats["dropped"] > 50 and sim.stats["corrupted"] > 50
        assert bus.stats["retries"] > 50


# ---------------------------------------------------------------- latency
def test_latency_warning(tmp_path):
    (tmp_path / "ttyUSB0").mkdir()
    (tmp_path / "ttyUSB0" / "latency_timer").write_text("16\n")
    (tmp_path / "ttyUSB1").mkdir()
    (tmp_path / "ttyUSB1" / "latency_timer").write_text("1\n")
    assert latency_timer_ms("/dev/ttyUSB0", tmp_path) == 16
    warning = latency_warning("/dev/ttyUSB0", tmp_path)
    assert "16 ms" in warning and "latency_timer" in warning and "\n" not in warning
    assert latency_warning("/dev/ttyUSB1", tmp_path) is None


def test_no_latency_warning_on_a_pty(sim):
    assert latency_timer_ms(sim.port) is None
    assert latency_warning(sim.port) is None


def test_goal_positions_are_written_only_inside_the_controllers_permit(sim) -> None:
    from drivers.errors import LimitError

    with ServoBus(sim.port) as bus:
        for write in (lambda: bus.write_goals({1: 1000}), lambda: bus.write_goal(1, 1000),
                      lambda: bus.write(1, 116, 4, 1000), lambda: bus.sync_write(114, 4, {1: 5})):
            with pytest.raises(LimitError, match="outside the motion controller"):
                write()
        bus.write(1, 65, 1, 1)  # anything else (here the LED) is written as before
