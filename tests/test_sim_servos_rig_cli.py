"""`gonio sim servos --rig examples/rig-sim.toml` against a plain dynamixel_sdk client: driving
the light arm into the camera stalls it and trips the overload bit; passing with room to
spare does not."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import EXAMPLES
from dynamixel_sdk import COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler
from referee import SIM_COLLISION_LOG

PH = PacketHandler(2.0)
TORQUE, GOAL, MOVING, POSITION, HW_ERROR = 64, 116, 122, 132, 70
TICKS_PER_DEG = 4096 / 360
GONIO = Path(sys.executable).with_name("gonio")


@pytest.fixture
def served(request: pytest.FixtureRequest) -> Iterator[PortHandler]:
    """The served rig's port; afterwards its stderr must show a contact of the arms (the
    simulator's warning) exactly when the test is marked ``collides`` (the child process is
    out of the referee's sight)."""
    proc = subprocess.Popen([str(GONIO), "sim", "servos", "--rig", str(EXAMPLES / "rig-sim.toml"),
                             "--time-scale", "10", "--stall-trip-s", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert path.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else path
        port = PortHandler(path)
        assert port.openPort() and port.setBaudRate(57600)
        for sid in (1, 2, 3):
            _ok(PH.write1ByteTxRx(port, sid, TORQUE, 1))
        yield port
        port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    err = proc.stderr.read()  # type: ignore[union-attr]
    assert (SIM_COLLISION_LOG in err) == bool(request.node.get_closest_marker("collides")), err


def _ok(reply: tuple) -> tuple:
    assert reply[-2] == COMM_SUCCESS, PH.getTxRxResult(reply[-2])
    return reply


def _read(port: PortHandler, sid: int, address: int, size: int) -> tuple[int, int]:
    fn = {1: PH.read1ByteTxRx, 4: PH.read4ByteTxRx}[size]
    for _ in range(3):
        value, result, error = fn(port, sid, address)
        if result == COMM_SUCCESS:
            return value - (2**32 if size == 4 and value >= 2**31 else 0), error
    raise AssertionError(PH.getTxRxResult(result))


def _goals(port: PortHandler, goals: dict[int, float], zero: dict[int, int]) -> None:
    writer = GroupSyncWrite(port, PH, GOAL, 4)
    for sid, deg in goals.items():
        writer.addParam(sid, list(round(zero[sid] + deg * TICKS_PER_DEG).to_bytes(4, "little", signed=True)))
    assert writer.txPacket() == COMM_SUCCESS


ZERO = {1: 2048, 2: 1024, 3: 2048}  # the rig file's zero_tick per servo


@pytest.mark.collides
def test_driving_the_light_arm_into_the_camera_stalls_and_trips(served: PortHandler) -> None:
    port = served
    _goals(port, {1: 60.0}, ZERO)  # camera parked at θ 45°, φ 0°: the light sweeps into it
    deadline = time.monotonic() + 10
    while _read(port, 1, HW_ERROR, 1)[0] == 0:
        assert time.monotonic() < deadline, "no overload trip"
        time.sleep(0.02)
    bits, alert = _read(port, 1, HW_ERROR, 1)
    assert bits & 0x20 and alert & 0x80  # overload bit, Alert on the status packet
    stuck_deg = (_read(port, 1, POSITION, 4)[0] - ZERO[1]) / TICKS_PER_DEG
    assert 35.0 < stuck_deg < 45.0  # stopped at the camera, far short of 60°
    assert _read(port, 1, TORQUE, 1)[0] == 0  # Shutdown: torque off


def test_passing_with_room_to_spare_is_no_error(served: PortHandler) -> None:
    port = served
    _goals(port, {3: 90.0}, ZERO)  # camera swings out of the light's plane first
    time.sleep(0.6)
    _goals(port, {1: 60.0}, ZERO)
    deadline = time.monotonic() + 10
    while abs(_read(port, 1, POSITION, 4)[0] - (ZERO[1] + 60 * TICKS_PER_DEG)) > 3:
        assert time.monotonic() < deadline, "the light arm did not get there"
        time.sleep(0.02)
    for sid in (1, 2, 3):
        assert _read(port, sid, HW_ERROR, 1) == (0, 0)
