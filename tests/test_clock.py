"""The discrete-event SteppedClock, the rig file's clock choice, and wire time on a stepped rig.

A stepped clock moves only in ``sleep``/``advance``; on it the servo simulator charges every
packet its 57600-baud time on the wire, so a sync read or write costs exactly what
:func:`acquisition.config.rig.sync_read_s` says, and a move costs its profile plus polling.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from guards import RecordingGuard

from acquisition.config.rig import MOTION_POLL_S, load_rig, move_bus_time_s, sync_read_s
from acquisition.devices.servos import open_servos
from acquisition.planning.planner import Planner
from acquisition.simworld.servos import make_clock
from drivers.dynamixel import Axis, MotionController, ServoBus
from drivers.errors import ConfigError
from simulators.clock import SimClock, SteppedClock
from simulators.dynamixel import SimServoBus

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
BYTE_S = 10 / 57600


def test_stepped_clock_moves_only_when_told() -> None:
    clock = SteppedClock()
    assert clock.now() == 0.0 and clock.time_scale == 1.0
    t0 = time.monotonic()
    clock.sleep(3600.0)  # an hour of rig time costs no host time
    assert time.monotonic() - t0 < 0.5
    assert clock.now() == 3600.0
    with clock.frozen():
        clock.advance(2.0)  # frozen() is a no-op: explicit advances still count
    clock.sleep(-1.0)
    clock.sleep(0.0)
    assert clock.now() == 3602.0
    with pytest.raises(ValueError, match="negative"):
        clock.advance(-0.1)
    with pytest.raises(ValueError, match="before 0"):
        SteppedClock(-1.0)
    assert isinstance(clock, SimClock)  # a drop-in wherever a SimClock is expected


def test_concurrent_advances_add_up() -> None:
    clock = SteppedClock(5.0)

    def work() -> None:
        for _ in range(2000):
            clock.advance(0.001)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert clock.now() == pytest.approx(5.0 + 8.0, abs=1e-9)


def rig_with(tmp_path: Path, simulation: str) -> Path:
    text = (EXAMPLES / "rig-sim.toml").read_text()
    text = text.replace("time_scale = 25.0", simulation)
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_rig_file_chooses_the_clock(tmp_path: Path) -> None:
    rig = load_rig(EXAMPLES / "rig-sim.toml")
    assert rig.sim_clock == "stepped" and isinstance(make_clock(rig), SteppedClock)
    scaled = load_rig(rig_with(tmp_path, 'time_scale = 4.0\nclock = "scaled"'))
    clock = make_clock(scaled)
    assert type(clock) is SimClock and clock.time_scale == 4.0
    # A stepped rig charges wire time to its clock; a scaled one delays replies in host time.
    for chosen, wire_time in ((rig, "clock"), (scaled, "host")):
        with open_servos(chosen, Planner(chosen), prepare=False) as servos:
            assert servos.sims
            assert {sim.wire_time for sim in servos.sims.values()} == {wire_time}
    with pytest.raises(ConfigError, match=r"clock.*'wall'.*stepped, scaled"):
        load_rig(rig_with(tmp_path, 'clock = "wall"'))


def test_sync_read_and_write_cost_their_wire_time() -> None:
    clock = SteppedClock()
    with SimServoBus([1, 2, 3], clock=clock, wire_time="clock") as sim, ServoBus(sim.port, 57600) as bus:
        t0 = clock.now()
        bus.read_positions([1, 2, 3])
        factory_delay_s = 500e-6  # a bare simulator keeps the factory Return Delay Time
        instruction, replies = sync_read_s(3, 4, 57600, factory_delay_s)
        assert clock.now() - t0 == pytest.approx(instruction + replies, abs=1e-9)
        assert instruction == pytest.approx(17 * BYTE_S) and replies > 3 * 15 * BYTE_S
        t0 = clock.now()
        with bus.permit_goals():  # as the motion controller does, after its guard
            bus.write_goals({1: 2000, 2: 2048, 3: 2100})  # no reply; the next read waits behind it
        bus.read_positions([1])
        one = sum(sync_read_s(1, 4, 57600, factory_delay_s))
        assert clock.now() - t0 == pytest.approx((14 + 15) * BYTE_S + one, abs=1e-9)


def test_a_move_costs_its_profile_plus_polling(tmp_path: Path) -> None:
    """One move of the rig on a stepped clock: the profile, then the first poll that sees the
    axes at rest (at most one control cycle later)."""
    rig = load_rig(EXAMPLES / "rig-sim.toml")
    planner = Planner(rig)
    with open_servos(rig, planner) as servos:
        clock = servos.clock
        assert isinstance(clock, SteppedClock) and servos.motion.poll_s == MOTION_POLL_S
        start = servos.motion.positions_deg()
        target = {"light_theta": -40.0, "camera_theta": 60.0, "camera_phi": 90.0}
        t0 = clock.now()
        servos.move_to(target)
        spent = clock.now() - t0
    profile = planner.time_model.move_s(start, target)
    cycle = MOTION_POLL_S + sum(sync_read_s(3, 20, 57600))
    before = (sum(sync_read_s(3, 84, 57600)) + sum(sync_read_s(3, 7, 57600))
              + (14 + 15) * BYTE_S)
    assert profile + before < spent < profile + before + cycle + sum(sync_read_s(3, 20, 57600))
    # The model charges the mean of that window.
    model = move_bus_time_s(rig.buses, rig.axes)
    assert before < model < before + cycle + sum(sync_read_s(3, 20, 57600))


def test_motion_controller_polls_on_a_stepped_clock() -> None:
    """The controller's poll sleeps advance the clock; the servo's motion follows it."""
    clock = SteppedClock()
    axis = Axis(name="a", servo_id=1, zero_tick=2048, direction=1, min_deg=-170, max_deg=170,
                profile_velocity=100, profile_acceleration=20)
    with SimServoBus([1], clock=clock, wire_time="clock") as sim, ServoBus(sim.port, 57600) as bus:
        motion = MotionController([axis], bus, guard=RecordingGuard(), sleep=clock.sleep,
                                  monotonic=clock.now, poll_s=0.01)
        motion.apply_profiles()
        motion.set_torque(True)
        t0, host0 = clock.now(), time.monotonic()
        reached = motion.move_to({"a": 150.0})
        spent = clock.now() - t0
    assert reached["a"] == pytest.approx(150.0, abs=0.3)
    v = 100 * 0.229 * 6.0
    a = 20 * 214.577 / 10.0
    profile = 150.0 / v + v / a
    assert profile < spent < profile + 0.2
    assert time.monotonic() - host0 < 20.0  # not slept in host time (generous for a loaded host)
