"""The simulated X-series bus, driven by the real dynamixel_sdk through its pty.

These tests call the SDK directly, without the driver's retries, so a reply that a heavily
loaded machine delivers after the SDK's ~34 ms packet timeout would fail them. The autouse
fixture below gives the SDK the timeout of an adapter with a 50 ms latency timer (~102 ms);
the driver's tests (test_servo_bus.py) and the benchmark keep the default.
"""

from __future__ import annotations

import math
import os
import re
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import dynamixel_sdk.port_handler
import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    DXL_HIBYTE,
    DXL_HIWORD,
    DXL_LOBYTE,
    DXL_LOWORD,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
    port_handler,
)

from drivers.errors import ConfigError
from simulators.clock import SimClock, SteppedClock
from simulators.dynamixel import SimServoBus, parse_fault
from simulators.dynamixel.profile import (
    TICKS_PER_S2_PER_ACCELERATION_UNIT,
    TICKS_PER_S_PER_VELOCITY_UNIT,
)
from simulators.dynamixel.protocol import BROADCAST_ID, Instruction, build_packet

PH = PacketHandler(2.0)
ACCESS, RANGE, LENGTH, INSTRUCTION, CRC, RESULT_FAIL = 7, 4, 5, 2, 3, 1


def signed32(value: int) -> int:
    return value - (1 << 32) if value >= 1 << 31 else value


def open_port(path: str, baud: int = 57600) -> PortHandler:
    port = PortHandler(path)
    assert port.openPort()
    assert port.setBaudRate(baud)
    return port


def raw_txrx(port: PortHandler, raw: bytes) -> tuple[list[int] | None, int]:
    """Send arbitrary bytes, read one status packet with the SDK's own parser."""
    port.clearPort()
    port.writePort(raw)
    port.setPacketTimeout(20)
    return PH.rxPacket(port, False)


@pytest.fixture(autouse=True)
def patient_sdk(monkeypatch):
    monkeypatch.setattr(port_handler, "LATENCY_TIMER", 50)  # read by the SDK at call time


@pytest.fixture
def port(sim):
    p = open_port(sim.port)
    yield p
    p.closePort()


# ---------------------------------------------------------------- instructions
def test_ping_read_write(sim, port):
    assert PH.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    assert PH.ping(port, 9)[1] == COMM_RX_TIMEOUT
    assert PH.read4ByteTxRx(port, 2, 132) == (2048, COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 2, 6) == (48, COMM_SUCCESS, 0)  # firmware
    assert PH.write1ByteTxRx(port, 2, 65, 1) == (COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 2, 65) == (1, COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 1, 65) == (0, COMM_SUCCESS, 0)
    assert PH.read2ByteTxRx(port, 3, 144) == (120, COMM_SUCCESS, 0)  # 12.0 V


def test_broadcast_ping_answers_in_id_order(clock):
    with SimServoBus([9, 2, 5], clock=clock) as sim:
        port = open_port(sim.port)
        found, result = PH.broadcastPing(port)
        assert result == COMM_SUCCESS and found == {2: [1020, 48], 5: [1020, 48], 9: [1020, 48]}
        # Raw order on the wire.
        port.clearPort()
        port.writePort(build_packet(BROADCAST_ID, Instruction.PING))
        deadline, raw = time.monotonic() + 1.0, b""
        while len(raw) < 3 * 14 and time.monotonic() < deadline:
            raw += port.readPort(64)
        assert [raw[i * 14 + 4] for i in range(3)] == [2, 5, 9]
        port.closePort()


def test_signed_positions_and_homing_offset(sim, port):
    assert PH.write4ByteTxRx(port, 1, 20, -3000 & 0xFFFFFFFF) == (COMM_SUCCESS, 0)
    value, result, _ = PH.read4ByteTxRx(port, 1, 132)
    assert result == COMM_SUCCESS and signed32(value) == 2048 - 3000
    assert sim.servos[1].sim_true_position_ticks() == pytest.approx(-952)


def test_sync_read_write_and_sync_write_gets_no_reply(sim, port, clock):
    for sid in (1, 2, 3):
        PH.write1ByteTxRx(port, sid, 64, 1)
    goals = {1: 1000, 2: 3000, 3: 2500}
    with clock.frozen():
        writer = GroupSyncWrite(port, PH, 116, 4)
        for sid, goal in goals.items():
            writer.addParam(sid, list(goal.to_bytes(4, "little")))
        assert writer.txPacket() == COMM_SUCCESS
        assert PH.ping(port, 3) == (1020, COMM_SUCCESS, 0)  # the write has been handled
        assert port.getBytesAvailable() == 0  # and nothing answered the SYNC_WRITE
        clock.advance(5.0)
        reader = GroupSyncRead(port, PH, 132, 4)
        for sid in goals:
            reader.addParam(sid)
        assert reader.txRxPacket() == COMM_SUCCESS
        assert {s: reader.getData(s, 132, 4) for s in goals} == goals


def test_bulk_read_write(sim, port, clock):
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        writer = GroupBulkWrite(port, PH)
        assert writer.addParam(1, 116, 4, list((3000).to_bytes(4, "little")))
        assert writer.addParam(2, 65, 1, [1])
        assert writer.txPacket() == COMM_SUCCESS
        PH.ping(port, 1)  # a round trip: the simulator has applied the write
        clock.advance(5.0)
        reader = GroupBulkRead(port, PH)
        reader.addParam(1, 132, 4)
        reader.addParam(2, 65, 1)
        assert reader.txRxPacket() == COMM_SUCCESS
        assert reader.getData(1, 132, 4) == 3000
        assert reader.getData(2, 65, 1) == 1


def test_reg_write_waits_for_action(sim, port):
    assert PH.regWriteTxRx(port, 1, 65, 1, [1]) == (COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 1, 69)[0] == 1  # registered instruction
    assert PH.read1ByteTxRx(port, 1, 65)[0] == 0
    assert PH.action(port, 1) == COMM_SUCCESS
    assert PH.read1ByteTxRx(port, 1, 65)[0] == 1
    assert PH.action(port, 1) == COMM_SUCCESS  # broadcast-free ACTION to ID: no reply awaited


def test_id_change_factory_reset_and_reboot(sim, port):
    assert PH.write1ByteTxRx(port, 3, 7, 30) == (COMM_SUCCESS, 0)
    assert PH.ping(port, 3)[1] == COMM_RX_TIMEOUT
    assert PH.ping(port, 30)[0] == 1020
    PH.write1ByteTxRx(port, 30, 65, 1)
    PH.write1ByteTxRx(port, 30, 31, 70)  # temperature limit (EEPROM)
    assert PH.factoryReset(port, 30, 0x02) == (COMM_SUCCESS, 0)  # keep ID and baud rate
    assert PH.read1ByteTxRx(port, 30, 31)[0] == 80
    assert PH.read1ByteTxRx(port, 30, 65)[0] == 0
    PH.write1ByteTxRx(port, 30, 64, 1)
    assert PH.reboot(port, 30) == (COMM_SUCCESS, 0)
    assert PH.read1ByteTxRx(port, 30, 64)[0] == 0  # torque off after reboot


# ---------------------------------------------------------------- error paths
def test_eeprom_is_read_only_while_torque_is_on(sim, port):
    PH.write1ByteTxRx(port, 1, 64, 1)
    assert PH.write4ByteTxRx(port, 1, 20, 100) == (COMM_SUCCESS, ACCESS)
    assert PH.write1ByteTxRx(port, 1, 9, 0) == (COMM_SUCCESS, ACCESS)
    PH.write1ByteTxRx(port, 1, 64, 0)
    assert PH.write4ByteTxRx(port, 1, 20, 100) == (COMM_SUCCESS, 0)


@pytest.mark.parametrize(
    ("address", "data", "error"),
    [
        (132, [0, 0, 0, 0], ACCESS),  # read-only
        (66, [0], ACCESS),  # reserved byte
        (146, [0, 0], ACCESS),  # beyond the end of the table
        (64, [2], RANGE),  # torque enable is 0/1
        (108, list((40000).to_bytes(4, "little")), RANGE),
        (116, [0, 8], LENGTH),  # half of goal position
        (64, [], LENGTH),
    ],
)
def test_write_errors(sim, port, address, data, error):
    before = bytes(sim.servos[1].mem)
    result, err = PH.writeTxRx(port, 1, address, len(data), data)
    assert (result, err) == (COMM_SUCCESS, error)
    assert bytes(sim.servos[1].mem)[:64] == before[:64]  # nothing written


def test_operating_mode_range_error(sim, port):
    assert PH.write1ByteTxRx(port, 1, 11, 2) == (COMM_SUCCESS, RANGE)
    assert PH.write1ByteTxRx(port, 1, 11, 4) == (COMM_SUCCESS, 0)


def test_read_errors(sim, port):
    assert PH.readTxRx(port, 1, 140, 10)[1:] == (COMM_SUCCESS, ACCESS)
    packet, result = raw_txrx(port, build_packet(1, Instruction.READ, bytes([132, 0])))
    assert result == COMM_SUCCESS and packet[8] == LENGTH


def test_unknown_instruction_gets_instruction_error(sim, port):
    packet, result = raw_txrx(port, build_packet(1, 0x20))
    assert result == COMM_SUCCESS and packet[8] == INSTRUCTION
    packet, result = raw_txrx(port, build_packet(1, Instruction.SYNC_WRITE, bytes(6)))
    assert result == COMM_SUCCESS and packet[8] == INSTRUCTION  # sync write needs broadcast


def test_bad_crc_gets_crc_error_and_is_not_executed(sim, port):
    bad = bytearray(build_packet(2, Instruction.WRITE, bytes([65, 0, 1])))
    bad[-1] ^= 0x55
    packet, result = raw_txrx(port, bytes(bad))
    assert result == COMM_SUCCESS and (packet[4], packet[8]) == (2, CRC)
    assert PH.read1ByteTxRx(port, 2, 65)[0] == 0
    bad = bytearray(build_packet(BROADCAST_ID, Instruction.PING))
    bad[-2] ^= 0x01
    assert raw_txrx(port, bytes(bad))[1] == COMM_RX_TIMEOUT  # broadcast: silence


def test_alert_bit_while_hardware_error(sim, port):
    PH.write1ByteTxRx(port, 1, 64, 1)
    sim.servos[1].sim_trip(0x20)
    value, result, error = PH.read1ByteTxRx(port, 1, 70)
    assert (value, result, error) == (0x20, COMM_SUCCESS, 0x80)
    assert PH.read1ByteTxRx(port, 1, 64)[0] == 0  # overload is in Shutdown: torque off
    assert PH.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0x80 | RESULT_FAIL)
    assert PH.ping(port, 2) == (1020, COMM_SUCCESS, 0)  # others unaffected
    assert PH.reboot(port, 1) == (COMM_SUCCESS, 0x80)
    assert PH.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)


def test_status_return_level(sim, port):
    PH.write1ByteTxOnly(port, 1, 68, 1)  # the new level already governs this write's reply
    assert PH.write1ByteTxRx(port, 1, 65, 1)[0] == COMM_RX_TIMEOUT  # writes: silent
    assert PH.read1ByteTxRx(port, 1, 65) == (1, COMM_SUCCESS, 0)  # but executed, reads answer
    PH.write1ByteTxOnly(port, 1, 68, 0)
    assert PH.read1ByteTxRx(port, 1, 65)[1] == COMM_RX_TIMEOUT
    assert PH.ping(port, 1)[1] == COMM_SUCCESS  # ping always answers
    PH.write1ByteTxOnly(port, 1, 68, 2)
    assert PH.write1ByteTxRx(port, 1, 65, 0) == (COMM_SUCCESS, 0)


def test_return_delay_time_delays_the_reply(sim, port):
    """508 µs of Return Delay Time is a floor under every reply: the fastest of many pings,
    interleaved so both servos see the same host load, differ by more than 0.3 ms."""
    def ping_s(sid: int) -> float:
        t0 = time.perf_counter()
        assert PH.ping(port, sid)[1] == COMM_SUCCESS
        return time.perf_counter() - t0

    PH.write1ByteTxRx(port, 1, 9, 0)
    PH.write1ByteTxRx(port, 2, 9, 254)  # 508 µs
    times: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(25):
        for sid in (1, 2):
            times[sid].append(ping_s(sid))
    assert min(times[2]) - min(times[1]) > 0.0003


def test_wire_time_models_the_baud_rate(clock):
    with SimServoBus([1], clock=clock, wire_time=True) as sim:
        port = open_port(sim.port)
        PH.write1ByteTxRx(port, 1, 9, 0)
        times = []
        for _ in range(9):
            t0 = time.perf_counter()
            assert PH.ping(port, 1)[1] == COMM_SUCCESS
            times.append(time.perf_counter() - t0)
        # 10-byte PING + 14-byte status at 10 bits per byte and 57600 baud ≈ 4.2 ms.
        assert statistics.median(times) > 24 * 10 / 57600
        port.closePort()


def test_clock_wire_time_charges_the_simulated_clock():
    """``wire_time="clock"``: each packet's bytes (10 bits each at the bus baud) and the servo's
    Return Delay Time advance a stepped clock, the instruction's before the servo acts on it."""
    clock = SteppedClock()
    byte_s = 10 / 9600
    with SimServoBus([1, 2], baud=9600, clock=clock, wire_time="clock") as sim:
        assert sim.wire_time == "clock"
        port = open_port(sim.port, 9600)
        # The servo reads its Realtime Tick (ms) once the 14-byte READ has arrived (14.6 ms).
        tick, result, _ = PH.read2ByteTxRx(port, 1, 120)
        assert result == COMM_SUCCESS and tick == 14
        delay_s = sim.servos[2].return_delay_s
        assert delay_s == pytest.approx(500e-6)  # factory Return Delay Time 250 × 2 µs
        t0 = clock.now()
        assert PH.ping(port, 2)[1] == COMM_SUCCESS  # 10-byte PING, delay, 14-byte status
        ping_s = 24 * byte_s + delay_s
        assert clock.now() - t0 == pytest.approx(ping_s, abs=1e-12)
        # A sync write gets no reply but still costs its 10 + 4 + 2 × (1 + 4) bytes.
        sync = GroupSyncWrite(port, PH, 116, 4)
        for sid in (1, 2):
            assert sync.addParam(sid, [DXL_LOBYTE(DXL_LOWORD(2048)), DXL_HIBYTE(DXL_LOWORD(2048)),
                                       DXL_LOBYTE(DXL_HIWORD(2048)), DXL_HIBYTE(DXL_HIWORD(2048))])
        t0 = clock.now()
        assert sync.txPacket() == COMM_SUCCESS
        assert PH.ping(port, 2)[1] == COMM_SUCCESS  # processed in order behind the write
        assert clock.now() - t0 == pytest.approx(24 * byte_s + ping_s, abs=1e-12)
        port.closePort()
    with pytest.raises(ConfigError, match="wire_time.*'clock'"):
        SimServoBus([1], clock=clock, wire_time="wall")  # type: ignore[arg-type]


def test_strict_baud_models_a_mismatch(clock):
    with SimServoBus([1], clock=clock, strict_baud=True) as sim:
        port = open_port(sim.port, 115200)
        assert PH.ping(port, 1)[1] == COMM_RX_TIMEOUT
        assert port.setBaudRate(57600)
        assert PH.ping(port, 1)[1] == COMM_SUCCESS
        port.closePort()


# ---------------------------------------------------------------- physics
def test_trapezoid_follows_the_x_series_profile(sim, port, clock):
    pv, pa = 100, 10
    v = pv * TICKS_PER_S_PER_VELOCITY_UNIT
    a = pa * TICKS_PER_S2_PER_ACCELERATION_UNIT
    t_acc = v / a
    assert t_acc * 1000 == pytest.approx(64 * pv / pa, rel=1e-3)  # the manual's formula
    PH.write4ByteTxRx(port, 1, 108, pa)
    PH.write4ByteTxRx(port, 1, 112, pv)
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        PH.write4ByteTxRx(port, 1, 116, 4048)
        d_acc = v * v / (2 * a)
        t_end = 2 * t_acc + (2000 - 2 * d_acc) / v
        start = clock.now()
        for t, expected in [(0.3, 0.5 * a * 0.09), (1.0, d_acc + v * (1.0 - t_acc))]:
            clock.advance(start + t - clock.now())
            pos = PH.read4ByteTxRx(port, 1, 132)[0]
            assert pos == pytest.approx(2048 + expected, abs=1)
            assert PH.read1ByteTxRx(port, 1, 122)[0] == 1
        assert signed32(PH.read4ByteTxRx(port, 1, 128)[0]) == pv  # cruising
        clock.advance(start + t_end - 0.01 - clock.now())
        assert PH.read1ByteTxRx(port, 1, 122)[0] == 1
        clock.advance(0.02)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 4048
        assert PH.read1ByteTxRx(port, 1, 122)[0] == 0
        assert PH.read4ByteTxRx(port, 1, 128)[0] == 0


def test_zero_profile_means_velocity_limit_and_infinite_acceleration(sim, port, clock):
    PH.write1ByteTxRx(port, 1, 64, 1)
    v = 200 * TICKS_PER_S_PER_VELOCITY_UNIT  # Velocity Limit default
    with clock.frozen():
        PH.write4ByteTxRx(port, 1, 116, 1048)
        clock.advance(0.1)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == pytest.approx(2048 - 0.1 * v, abs=1)
        clock.advance(1000 / v)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 1048


def test_time_based_profile(sim, port, clock):
    PH.write1ByteTxRx(port, 1, 10, 4)  # drive mode: time-based profile
    PH.write4ByteTxRx(port, 1, 108, 250)  # acceleration time, ms
    PH.write4ByteTxRx(port, 1, 112, 1000)  # total time, ms
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        PH.write4ByteTxRx(port, 1, 116, 3048)
        clock.advance(0.5)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == pytest.approx(2548, abs=1)
        clock.advance(0.501)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 3048


def test_position_limits_clamp_goals(sim, port, clock):
    PH.write4ByteTxRx(port, 1, 48, 3000)
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        assert PH.write4ByteTxRx(port, 1, 116, 4000) == (COMM_SUCCESS, 0)
        assert PH.read4ByteTxRx(port, 1, 116)[0] == 3000
        clock.advance(5)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 3000


def test_torque_on_holds_present_position(sim, port, clock):
    PH.write4ByteTxRx(port, 1, 116, 100)  # goal written with torque off: no motion
    with clock.frozen():
        clock.advance(5)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 2048
        PH.write1ByteTxRx(port, 1, 64, 1)
        assert PH.read4ByteTxRx(port, 1, 116)[0] == 2048  # goal := present, no jump
        clock.advance(5)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 2048


def test_temperature_rises_with_load_and_falls_at_rest(sim, port, clock):
    PH.write4ByteTxRx(port, 1, 112, 1)  # very slow: ~16 ticks/s, the move lasts minutes
    for sid in (1, 2):
        PH.write1ByteTxRx(port, sid, 64, 1)
    with clock.frozen():
        t0 = PH.read1ByteTxRx(port, 3, 146)[0]
        PH.write4ByteTxRx(port, 1, 116, 4095)
        clock.advance(120)
        moving, holding, idle = (PH.read1ByteTxRx(port, s, 146)[0] for s in (1, 2, 3))
        assert moving > holding + 5 and holding > idle and idle <= t0
        assert PH.read1ByteTxRx(port, 1, 122)[0] == 1
        PH.write1ByteTxRx(port, 1, 64, 0)
        clock.advance(1200)
        assert PH.read1ByteTxRx(port, 1, 146)[0] < moving - 10


def test_obstruction_stalls_then_trips_overload(sim, port, clock):
    sim.servos[1].sim_set_obstruction(None, 2500)
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        PH.write4ByteTxRx(port, 1, 116, 3500)
        clock.advance(0.5)
        assert PH.read4ByteTxRx(port, 1, 132)[0] == 2500
        assert PH.read1ByteTxRx(port, 1, 122) == (1, COMM_SUCCESS, 0)
        clock.advance(2.0)
        value, _, error = PH.read1ByteTxRx(port, 1, 70)
        assert (value, error) == (0x20, 0x80)
        assert PH.read1ByteTxRx(port, 1, 64)[0] == 0
        assert sim.servos[1].sim_true_position_ticks() == 2500


def test_input_voltage_fault_sets_bit0_but_keeps_torque(clock):
    with SimServoBus([1], clock=clock, faults=["voltage:id=1,volts=9.0,after=2"]) as sim:
        port = open_port(sim.port)
        PH.write1ByteTxRx(port, 1, 64, 1)
        with clock.frozen():
            assert PH.read2ByteTxRx(port, 1, 144) == (120, COMM_SUCCESS, 0)
            clock.advance(2.5)
            assert PH.read2ByteTxRx(port, 1, 144) == (90, COMM_SUCCESS, 0x80)
            assert PH.read1ByteTxRx(port, 1, 70)[0] == 0x01
            assert PH.read1ByteTxRx(port, 1, 64)[0] == 1
        port.closePort()


# ---------------------------------------------------------------- faults
def test_overload_fault_after_sim_seconds(clock):
    with SimServoBus([1, 2], clock=clock, faults=["overload:id=2,after=5"]) as sim:
        port = open_port(sim.port)
        for sid in (1, 2):
            PH.write1ByteTxRx(port, sid, 64, 1)
        with clock.frozen():
            clock.advance(4.0)
            assert PH.read1ByteTxRx(port, 2, 70) == (0, COMM_SUCCESS, 0)
            clock.advance(1.5)
            assert PH.read1ByteTxRx(port, 2, 70) == (0x20, COMM_SUCCESS, 0x80)
            assert PH.read1ByteTxRx(port, 2, 64)[0] == 0
            assert PH.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)
            assert PH.reboot(port, 2)[0] == COMM_SUCCESS
            assert PH.write1ByteTxRx(port, 2, 64, 1) == (COMM_SUCCESS, 0)  # one-shot fault
            clock.advance(10)
            assert PH.read1ByteTxRx(port, 2, 70) == (0, COMM_SUCCESS, 0)
        port.closePort()


def test_overheat_fault_trips_and_needs_cooling(clock):
    with SimServoBus([1], clock=clock, faults=["overheat:id=1"]) as sim:
        port = open_port(sim.port)
        PH.write1ByteTxRx(port, 1, 64, 1)
        with clock.frozen():
            clock.advance(60)
            temp = PH.read1ByteTxRx(port, 1, 146)[0]
            assert 40 < temp < 80
            for _ in range(200):
                clock.advance(2)
                if PH.read1ByteTxRx(port, 1, 70)[0]:
                    break
            assert PH.read1ByteTxRx(port, 1, 70) == (0x04, COMM_SUCCESS, 0x80)
            assert PH.read1ByteTxRx(port, 1, 146)[0] >= 78
            assert PH.read1ByteTxRx(port, 1, 64)[0] == 0
            PH.reboot(port, 1)
            assert PH.read1ByteTxRx(port, 1, 70)[0] == 0x04  # still hot
            clock.advance(600)
            PH.reboot(port, 1)
            assert PH.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)
        port.closePort()


@pytest.mark.parametrize(
    ("spec", "result"),
    [("drop=1", COMM_RX_TIMEOUT), ("corrupt=1", COMM_RX_CORRUPT), ("delay=150", COMM_RX_TIMEOUT),
     ("delay=3", COMM_SUCCESS), ("drop:id=2,p=1", COMM_SUCCESS)],
)
def test_wire_faults(clock, spec, result):
    with SimServoBus([1, 2], clock=clock, faults=[spec]) as sim:
        port = open_port(sim.port)
        t0 = time.perf_counter()
        assert PH.ping(port, 1)[1] == result
        if spec == "delay=3":
            assert time.perf_counter() - t0 > 0.003
        if spec.startswith("drop:id=2"):
            assert PH.ping(port, 2)[1] == COMM_RX_TIMEOUT
        port.closePort()


def test_seeded_faults_repeat(monkeypatch):
    # A reply the host delays past the SDK's 34 ms would read as one more loss: wait 0.3 s.
    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 150)

    def run(seed: int) -> tuple[int, ...]:
        with SimServoBus([1], faults=["drop=0.5"], seed=seed) as sim:
            port = open_port(sim.port)
            PH.write1ByteTxRx(port, 1, 9, 0)
            out = tuple(PH.read1ByteTxRx(port, 1, 65)[1] for _ in range(12))
            port.closePort()
            return out

    first = run(7)
    assert run(7) == first
    assert COMM_RX_TIMEOUT in first and COMM_SUCCESS in first


@pytest.mark.parametrize(
    ("spec", "kinds"),
    [("drop=0.05,corrupt=0.05", [("drop", None, {"p": 0.05}), ("corrupt", None, {"p": 0.05})]),
     ("overload:id=2,after=20", [("overload", 2, {"after": 20.0})]),
     ("overheat:id=3", [("overheat", 3, {})]),
     ("delay=5", [("delay", None, {"ms": 5.0})]),
     ("obstruction:id=1,max=3000", [("obstruction", 1, {"max": 3000.0})])],
)
def test_fault_specs_parse(spec, kinds):
    assert [(f.kind, f.servo_id, f.params) for f in parse_fault(spec)] == kinds


@pytest.mark.parametrize(
    "spec", ["", "drop", "drop=2", "explode=1", "overload:after=3", "overload:id=x",
             "overheat:id=1,speed=3", "delay=-1", "obstruction:id=1"],
)
def test_bad_fault_specs_raise_one_line_config_errors(spec):
    with pytest.raises(ConfigError) as info:
        parse_fault(spec)
    assert "\n" not in str(info.value)


def test_bus_arguments_are_checked():
    with pytest.raises(ConfigError, match="253"):
        SimServoBus([1, 253])
    with pytest.raises(ConfigError, match="unique"):
        SimServoBus([1, 1])
    with pytest.raises(ConfigError, match="12345"):
        SimServoBus([1], baud=12345)
    with pytest.raises(ConfigError, match=r"\[4\]"):
        SimServoBus([1], faults=["overload:id=4"], strict_fault_ids=True)
    SimServoBus([1], faults=["overload:id=4"])  # another bus of the rig may have servo 4


# ---------------------------------------------------------------- lifecycle
def test_stop_is_fast_and_removes_the_device(clock):
    sim = SimServoBus([1], clock=clock)
    path = sim.start()
    assert os.path.exists(path)
    t0 = time.perf_counter()
    sim.stop()
    assert time.perf_counter() - t0 < 0.05
    assert not os.path.exists(path)


def test_several_buses_at_once(clock):
    with SimServoBus([1, 2], clock=clock) as a, SimServoBus([1, 7], clock=clock) as b:
        assert a.port != b.port
        pa, pb = open_port(a.port), open_port(b.port)
        PH.write1ByteTxRx(pa, 1, 65, 1)
        assert PH.read1ByteTxRx(pb, 1, 65)[0] == 0
        assert PH.ping(pa, 7)[1] == COMM_RX_TIMEOUT and PH.ping(pb, 7)[0] == 1020
        pa.closePort()
        pb.closePort()


def test_many_ids_on_one_bus(clock):
    ids = list(range(1, 253, 12))
    with SimServoBus(ids, clock=clock) as sim:
        port = open_port(sim.port)
        for s in sim.servos.values():
            s.mem[9] = 0
        reader = GroupSyncRead(port, PH, 132, 4)
        for sid in ids:
            reader.addParam(sid)
        assert reader.txRxPacket() == COMM_SUCCESS
        assert all(reader.getData(sid, 132, 4) == 2048 for sid in ids)
        port.closePort()


def test_serve_servos_forever_prints_the_path_first_and_stops_on_sigterm():
    code = ("from simulators.dynamixel import serve_servos_forever as s;"
            "raise SystemExit(s([1, 2], 57600, 1.0, [], 0, ready=lambda b: print(b.port, flush=True)))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()
        port = open_port(path)
        assert PH.ping(port, 2)[0] == 1020
        port.closePort()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()


# ---------------------------------------------------------------- the SDK's example programs
# The ROBOTIS protocol-2.0 examples (ping.py, read_write.py, sync_read_write.py,
# bulk_read_write.py) set their own baud rate (1M / 2M for the X series) and talk to IDs 1, 2.
# These tests make the same SDK calls in the same order; the simulator runs at 57600 like
# `gonio sim servos --ids 1,2 --baud 57600`, which answers any client speed by default.
EXAMPLE_BAUD = 1_000_000


@pytest.fixture
def example_port():
    with SimServoBus([1, 2], baud=57600, clock=SimClock(20.0)) as sim:
        port = open_port(sim.port, EXAMPLE_BAUD)
        yield port
        port.closePort()


def test_example_ping(example_port):
    model, result, error = PH.ping(example_port, 1)
    assert (model, result, error) == (1020, COMM_SUCCESS, 0)


def _goal_bytes(goal: int) -> list[int]:
    return [DXL_LOBYTE(DXL_LOWORD(goal)), DXL_HIBYTE(DXL_LOWORD(goal)),
            DXL_LOBYTE(DXL_HIWORD(goal)), DXL_HIBYTE(DXL_HIWORD(goal))]


def test_example_read_write(example_port):
    port = example_port
    assert PH.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    for goal in (0, 4095, 0):  # three key presses, then ESC
        assert PH.write4ByteTxRx(port, 1, 116, goal) == (COMM_SUCCESS, 0)
        for _ in range(10_000):
            present, result, error = PH.read4ByteTxRx(port, 1, 132)
            assert (result, error) == (COMM_SUCCESS, 0)
            if not abs(goal - present) > 20:
                break
        else:
            pytest.fail("the servo never reached the goal")
    assert PH.write1ByteTxRx(port, 1, 64, 0) == (COMM_SUCCESS, 0)


def test_example_sync_read_write(example_port):
    port = example_port
    writer = GroupSyncWrite(port, PH, 116, 4)
    reader = GroupSyncRead(port, PH, 132, 4)
    for sid in (1, 2):
        assert PH.write1ByteTxRx(port, sid, 64, 1) == (COMM_SUCCESS, 0)
        assert reader.addParam(sid)
    for goal in (0, 4095):
        for sid in (1, 2):
            assert writer.addParam(sid, _goal_bytes(goal))
        assert writer.txPacket() == COMM_SUCCESS
        writer.clearParam()
        for _ in range(10_000):
            assert reader.txRxPacket() == COMM_SUCCESS
            assert reader.isAvailable(1, 132, 4) and reader.isAvailable(2, 132, 4)
            p1, p2 = reader.getData(1, 132, 4), reader.getData(2, 132, 4)
            if not (abs(goal - p1) > 20 and abs(goal - p2) > 20):
                break
        else:
            pytest.fail("the servos never reached the goal")
    reader.clearParam()
    for sid in (1, 2):
        assert PH.write1ByteTxRx(port, sid, 64, 0) == (COMM_SUCCESS, 0)


def test_example_bulk_read_write(example_port):
    port = example_port
    writer, reader = GroupBulkWrite(port, PH), GroupBulkRead(port, PH)
    for sid in (1, 2):
        assert PH.write1ByteTxRx(port, sid, 64, 1) == (COMM_SUCCESS, 0)
    assert reader.addParam(1, 132, 4) and reader.addParam(2, 65, 1)
    for goal, led in ((0, 0), (4095, 1)):
        assert writer.addParam(1, 116, 4, _goal_bytes(goal))
        assert writer.addParam(2, 65, 1, [led])
        assert writer.txPacket() == COMM_SUCCESS
        writer.clearParam()
        for _ in range(10_000):
            assert reader.txRxPacket() == COMM_SUCCESS
            assert reader.isAvailable(1, 132, 4) and reader.isAvailable(2, 65, 1)
            present, led_read = reader.getData(1, 132, 4), reader.getData(2, 65, 1)
            if not abs(goal - present) > 20:
                break
        else:
            pytest.fail("the servo never reached the goal")
        assert led_read == led
    for sid in (1, 2):
        assert PH.write1ByteTxRx(port, sid, 64, 0) == (COMM_SUCCESS, 0)


def test_true_position_is_continuous_between_ticks(sim, port, clock):
    PH.write1ByteTxRx(port, 1, 64, 1)
    with clock.frozen():
        PH.write4ByteTxRx(port, 1, 116, 3000)
        clock.advance(0.0001)
        true = sim.servos[1].sim_true_position_ticks()
        assert 2048 < true < 2049 and not math.isclose(true, round(true))


# ---------------------------------------------------------------- unmodified example programs
# The ROBOTIS example scripts read keys with getch() from a terminal (tty.setraw on stdin), so a
# test runs them with a pty as stdin, waits for each "Press any key" prompt and types a key, then
# ESC. Only the DEVICENAME line is changed: it names the device path `gonio sim servos --ids 1,2`
# prints first (the command itself, in a child process, as a user would run it). The scripts are
# not vendored: set GONIO_DXL_EXAMPLES to a local DynamixelSDK/python/tests/protocol2_0
# directory to run them; the harness and the command are always exercised on a small script
# written in the same style.
EXAMPLES_DIR = os.environ.get("GONIO_DXL_EXAMPLES")
PROMPT = b"Press any key to continue!"
GONIO = Path(sys.executable).with_name("gonio")


@contextmanager
def gonio_sim_servos(*args: str) -> Iterator[str]:
    """Run ``gonio sim servos ARGS`` in a child process; yield the device path it prints
    first; stop it with SIGTERM (it must exit 0)."""
    proc = subprocess.Popen([str(GONIO), "sim", "servos", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert path.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else path
        yield path
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0, proc.stderr.read()  # type: ignore[union-attr]
    finally:
        proc.kill()
        proc.wait(timeout=10)

STYLE_SCRIPT = '''\
import sys, tty, termios
fd = sys.stdin.fileno()
old_settings = termios.tcgetattr(fd)
def getch():
    try:
        tty.setraw(sys.stdin.fileno())
        ch = sys.stdin.read(1)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old_settings)
    return ch
from dynamixel_sdk import *
DEVICENAME = '/dev/ttyUSB0'
portHandler = PortHandler(DEVICENAME)
packetHandler = PacketHandler(2.0)
if not (portHandler.openPort() and portHandler.setBaudRate(1000000)):
    print("Failed to open the port")
    quit()
led = 0
while 1:
    print("Press any key to continue! (or press ESC to quit!)", flush=True)
    if getch() == chr(0x1b):
        break
    led = 1 - led
    result, error = packetHandler.write1ByteTxRx(portHandler, 2, 65, led)
    value, result, error = packetHandler.read1ByteTxRx(portHandler, 2, 65)
    print("[ID:002] LED:%d %s" % (value, packetHandler.getTxRxResult(result)), flush=True)
portHandler.closePort()
'''


def run_example(source: str, device: str, tmp_path, presses: int = 3,
                timeout_s: float = 60.0) -> str:
    """Run an example script (DEVICENAME replaced) on a pty stdin; return its output."""
    script = re.sub(r"^DEVICENAME\s*=.*$", f"DEVICENAME = {device!r}", source, count=1,
                    flags=re.M)
    assert script != source, "no DEVICENAME line to change"
    path = tmp_path / "example.py"
    path.write_text(script)
    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, str(path)], stdin=slave, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    os.close(slave)
    out, deadline, pressed = b"", time.monotonic() + timeout_s, 0
    try:
        os.set_blocking(proc.stdout.fileno(), False)
        while proc.poll() is None:
            assert time.monotonic() < deadline, f"example hung; output so far:\n{out.decode()}"
            chunk = proc.stdout.read() or b""
            out += chunk
            if out.count(PROMPT) > pressed:
                pressed += 1
                os.write(master, b"\x1b" if pressed > presses else b" ")
            if not chunk:
                time.sleep(0.01)
        out += proc.stdout.read() or b""
    finally:
        proc.kill()
        os.close(master)
    assert proc.returncode == 0, out.decode()
    return out.decode()


def test_example_harness_drives_a_getch_script_against_gonio_sim_servos(tmp_path):
    with gonio_sim_servos("--ids", "1,2") as device:
        out = run_example(STYLE_SCRIPT, device, tmp_path, presses=3)
    assert out.count("[ID:002] LED:") == 3  # three key presses, then ESC ended it
    assert "[ID:002] LED:1 [TxRxResult] Communication success" in out


@pytest.mark.skipif(not EXAMPLES_DIR, reason="set GONIO_DXL_EXAMPLES to the SDK's examples")
@pytest.mark.parametrize("name", ["ping", "read_write", "sync_read_write", "bulk_read_write"])
def test_robotis_example_runs_unchanged(name, tmp_path):
    source = (Path(EXAMPLES_DIR) / f"{name}.py").read_text()
    # The command as documented; --time-scale only makes the servos' moves 20 × shorter.
    with gonio_sim_servos("--ids", "1,2", "--time-scale", "20") as device:
        out = run_example(source, device, tmp_path, presses=3)
    assert "Succeeded to open the port" in out and "Failed" not in out
    assert "[RxPacketError]" not in out and "[TxRxResult]" not in out
