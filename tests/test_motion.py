"""Axis conversions and MotionController moves on the simulated bus (real SDK, pty)."""

from __future__ import annotations

import math
import threading
import time

import pytest
from guards import RecordingGuard
from hypothesis import given
from hypothesis import strategies as st

from drivers.dynamixel import (
    Axis,
    MotionController,
    MotionTimeoutError,
    OverloadError,
    ServoBus,
    TorqueOffError,
)
from drivers.errors import CollisionError, ConfigError, LimitError, SafetyStop
from simulators.clock import SimClock
from simulators.dynamixel import SimServoBus
from simulators.dynamixel.profile import limits_from_registers, plan

AXES = [
    Axis("theta_i", 1, min_deg=-90, max_deg=90, profile_velocity=200, profile_acceleration=50),
    Axis("theta_r", 2, min_deg=-90, max_deg=90, direction=-1, profile_velocity=200,
         profile_acceleration=50),
    Axis("phi", 3, min_deg=-170, max_deg=170, zero_tick=2048),
]


# ---------------------------------------------------------------- Axis
@given(st.floats(-90, 90), st.sampled_from([1, -1]), st.integers(1100, 3000))
def test_deg_ticks_round_trip_within_half_a_tick(deg, direction, zero):
    axis = Axis("a", 1, min_deg=-90, max_deg=90, zero_tick=zero, direction=direction)
    ticks = axis.deg_to_ticks(deg)
    assert abs(axis.ticks_to_deg(ticks) - deg) <= axis.deg_per_tick / 2 + 1e-9


def test_axis_mapping_and_direction():
    assert AXES[0].deg_to_ticks(90) == 2048 + 1024
    assert AXES[1].deg_to_ticks(90) == 2048 - 1024
    assert AXES[1].ticks_to_deg(1024) == 90


@pytest.mark.parametrize("deg", [90.01, -91, math.nan, math.inf])
def test_deg_to_ticks_refuses_targets_outside_the_limits(deg):
    with pytest.raises(LimitError) as info:
        AXES[0].deg_to_ticks(deg)
    assert "theta_i" in str(info.value) and "nothing was sent" in str(info.value)


@pytest.mark.parametrize(
    "kwargs",
    [dict(min_deg=10, max_deg=0), dict(min_deg=0, max_deg=10, direction=2),
     dict(min_deg=-200, max_deg=200), dict(min_deg=0, max_deg=10, profile_velocity=-1)],
)
def test_bad_axis_definitions_are_config_errors(kwargs):
    with pytest.raises(ConfigError):
        Axis("bad", 1, **kwargs)


@pytest.mark.parametrize("pv, pa, delta", [(200, 50, 90.0), (100, 10, 5.0), (0, 0, 45.0)])
def test_move_time_matches_the_simulated_profile(pv, pa, delta):
    axis = Axis("a", 1, min_deg=-180, max_deg=179, profile_velocity=pv, profile_acceleration=pa)
    ticks = delta / axis.deg_per_tick
    vmax, amax = limits_from_registers(pv, pa, 200)
    assert axis.move_time_s(delta) == pytest.approx(plan(0, 0, 0, ticks, vmax, amax).end, rel=1e-6)


# ---------------------------------------------------------------- controller fixtures
@pytest.fixture
def clock():
    return SimClock(10.0)


@pytest.fixture
def bus(sim):
    with ServoBus(sim.port, name="arms") as b:
        b.set_return_delay([1, 2, 3], 0)
        yield b


@pytest.fixture
def guard():
    return RecordingGuard()


@pytest.fixture
def mc(bus, guard):
    controller = MotionController(AXES, bus, guard=guard)
    controller.apply_profiles()
    controller.set_torque(True)
    return controller


def wait_still(bus: ServoBus, ids, timeout_s: float = 5.0):
    """Poll until no servo moves; return their status."""
    deadline = time.monotonic() + timeout_s
    while True:
        status = bus.read_status(ids)
        if not any(s.moving for s in status.values()):
            return status
        assert time.monotonic() < deadline, "servos kept moving"
        time.sleep(0.005)


def true_deg(sim: SimServoBus, axis: Axis) -> float:
    return axis.ticks_to_deg(sim.servos[axis.servo_id].sim_true_position_ticks())


# ---------------------------------------------------------------- moves
def test_controller_needs_a_guard(bus):
    with pytest.raises(ConfigError, match="guard"):
        MotionController(AXES, bus, guard=None)


def test_move_is_guarded_sent_once_and_confirmed_by_readback(mc, sim, guard):
    sleeps = []

    def sleep(s):
        sleeps.append(s)
        time.sleep(s)

    mc._sleep = sleep
    before = sim.instructions["SYNC_WRITE"]
    result = mc.move_to({"theta_i": 30.0, "theta_r": -45.0, "phi": 120.0})
    assert guard.targets == [{"theta_i": 30.0, "theta_r": -45.0, "phi": 120.0}]
    start = guard.calls[0][0]
    assert set(start) == {"theta_i", "theta_r", "phi"}  # the guard sees where every axis stands
    assert sim.instructions["SYNC_WRITE"] - before == 1  # one sync write for the bus
    for name, target in {"theta_i": 30.0, "theta_r": -45.0, "phi": 120.0}.items():
        axis = mc.axes[name]
        assert result[name] == pytest.approx(target, abs=3 * axis.deg_per_tick)
        assert true_deg(sim, axis) == pytest.approx(result[name], abs=axis.deg_per_tick)
    assert sleeps  # polled with the given sleep
    assert mc.positions_deg() == result


def test_guard_refusal_sends_nothing(mc, sim):
    class Refuse:
        def check_move(self, start, targets):
            raise CollisionError(f"arms collide at {targets}")

    mc.guard = Refuse()
    writes = ("WRITE", "SYNC_WRITE", "REG_WRITE", "BULK_WRITE")
    before = sum(sim.instructions[k] for k in writes)
    with pytest.raises(CollisionError):
        mc.move_to({"theta_i": 10.0})
    assert sum(sim.instructions[k] for k in writes) == before  # it may read where axes stand


def test_soft_limits_and_unknown_axes_send_nothing(mc, sim):
    before = sum(sim.instructions.values())
    with pytest.raises(LimitError, match="theta_r"):
        mc.move_to({"theta_i": 10.0, "theta_r": 95.0})
    with pytest.raises(ConfigError, match="gamma"):
        mc.move_to({"gamma": 1.0})
    assert sum(sim.instructions.values()) == before
    assert sim.servos[1].sim_true_position_ticks() == 2048


def test_torque_off_is_refused_before_sending(mc, sim, bus):
    bus.set_torque([3], False)
    with pytest.raises(TorqueOffError, match="axis 'phi'.*gonio torque on"):
        mc.move_to({"phi": 10.0, "theta_i": 5.0})
    assert sim.servos[1].sim_true_position_ticks() == 2048


def test_overload_during_a_move_names_the_axis_and_stops_all(clock):
    with SimServoBus([1, 2, 3], clock=clock, faults=["overload:id=2,after=0.5"]) as sim, \
            ServoBus(sim.port, name="arms") as bus:
        mc = MotionController(AXES, bus, guard=RecordingGuard())
        with clock.frozen():  # set-up costs no simulated time, however loaded the machine
            slow_down(mc)
            mc.set_torque(True)
        with pytest.raises(OverloadError) as info:
            mc.move_to({"theta_i": 80.0, "theta_r": 80.0, "phi": 160.0})
        message = str(info.value)
        assert "axis 'theta_r'" in message and "overload" in message
        assert "gonio reboot theta_r" in message and "\n" not in message
        # The others got goal := present at once (they brake and settle there), torque on.
        status = wait_still(bus, [1, 3])
        assert all(s.torque_on for s in status.values())
        assert all(abs(s.goal - s.position) <= 1 for s in status.values())
        assert 0 < AXES[0].ticks_to_deg(status[1].goal) < 80


def slow_down(mc: MotionController) -> None:
    """Profiles slow enough (≈ 40 °/s) that a loaded test machine can stop a move mid-way."""
    for name, axis in mc.axes.items():
        mc._bus[name].set_profile(axis.servo_id, velocity=30, acceleration=10)


def test_stop_halts_a_move_in_progress(mc, sim):
    slow_down(mc)
    outcome = {}

    def run():
        try:
            mc.move_to({"theta_i": 85.0, "phi": -160.0})
        except SafetyStop as exc:
            outcome["error"] = exc

    mover = threading.Thread(target=run)
    mover.start()
    deadline = time.monotonic() + 5
    while abs(true_deg(sim, AXES[0])) < 10:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    stopped = mc.stop()
    mover.join(5)
    assert isinstance(outcome.get("error"), SafetyStop)
    wait_still(mc._bus["phi"], [1, 3])  # never re-sent its goals after the stop
    for name in ("theta_i", "phi"):
        axis = mc.axes[name]
        assert true_deg(sim, axis) == pytest.approx(stopped[name], abs=axis.deg_per_tick)
    assert 10 <= stopped["theta_i"] < 80
    assert all(sim.servos[i].torque_on for i in (1, 2, 3))


def test_ctrl_c_during_a_move_stops_all_axes(mc, sim):
    slow_down(mc)
    calls = []

    def sleep(s):
        calls.append(s)
        if len(calls) == 3:
            raise KeyboardInterrupt
        time.sleep(0.01)

    mc._sleep = sleep
    with pytest.raises(KeyboardInterrupt):
        mc.move_to({"theta_i": 85.0, "theta_r": 85.0})
    status = wait_still(mc._bus["theta_i"], [1, 2])
    for sid, axis in ((1, AXES[0]), (2, AXES[1])):
        assert abs(status[sid].goal - status[sid].position) <= 1
        assert 0 < axis.ticks_to_deg(status[sid].goal) < 80
        assert status[sid].torque_on


def test_servo_clamping_the_goal_is_reported(mc, sim, bus):
    bus.set_torque([1], False)
    bus.write(1, 48, 4, 2500)  # Max Position Limit below the axis' 90°
    bus.set_torque([1], True)
    with pytest.raises(LimitError, match="Position Limit"):
        mc.move_to({"theta_i": 60.0})


def test_timeout_stops_and_names_the_lagging_axis(mc, sim):
    sim.servos[3].sim_set_obstruction(None, 2200)
    with pytest.raises(MotionTimeoutError) as info:
        mc.move_to({"phi": 90.0, "theta_i": 1.0}, timeout_s=0.05)
    assert "phi" in str(info.value) and "obstruction" in str(info.value)
    status = mc._bus["phi"].read_status([3])[3]
    assert status.goal == status.position


def test_two_buses_one_sync_write_each(clock):
    with SimServoBus([1, 2], clock=clock) as sim_a, SimServoBus([1], clock=clock) as sim_b, \
            ServoBus(sim_a.port, name="a") as bus_a, ServoBus(sim_b.port, name="b") as bus_b:
        axes = [AXES[0], AXES[1], Axis("phi", 1, min_deg=-170, max_deg=170)]
        mc = MotionController(axes, {"theta_i": bus_a, "theta_r": bus_a, "phi": bus_b},
                              guard=RecordingGuard())
        mc.set_torque(True)
        result = mc.move_to({"theta_i": 20.0, "theta_r": 10.0, "phi": -30.0})
        assert result == pytest.approx({"theta_i": 20.0, "theta_r": 10.0, "phi": -30.0},
                                       abs=0.3)
        assert sim_a.instructions["SYNC_WRITE"] == 1 and sim_b.instructions["SYNC_WRITE"] == 1
        assert sim_b.servos[1].sim_true_position_ticks() == axes[2].deg_to_ticks(-30.0)


def test_same_servo_twice_is_a_config_error(bus):
    with pytest.raises(ConfigError, match="both use servo 1"):
        MotionController([AXES[0], Axis("x", 1, min_deg=0, max_deg=1)], bus, guard=RecordingGuard())
