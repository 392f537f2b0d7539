"""The guard on the wire, on the rig's simulated servos with their solid parts (the test-wide
referee fails any of these whose arms touch): the sync-write subset rule, guarded braking,
and a partial move (one servo missed the goal sync write) re-planned from the read-back pose.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager

import pytest
from conftest import EXAMPLES
from guards import RecordingGuard

from acquisition.config.rig import load_rig
from acquisition.devices.servos import ServoRig, open_servos, routed_move
from acquisition.planning.planner import Planner
from drivers.dynamixel import Axis, MotionController, ServoBus
from drivers.errors import CollisionError
from simulators.clock import SimClock, SteppedClock
from simulators.dynamixel import SimServoBus

RIG = EXAMPLES / "rig-sim.toml"
LIGHT, CAMERA_PHI = 1, 3
"""Servo IDs of light_theta and camera_phi on the example rig."""
DEG = 0.1


@contextmanager
def rig_servos(clock: SteppedClock | SimClock, faults: tuple[str, ...] = ()) -> Iterator[ServoRig]:
    rig = load_rig(RIG)
    with open_servos(rig, Planner(rig), clock=clock, sim_faults=faults) as servos:
        yield servos


def only_sim(servos: ServoRig) -> SimServoBus:
    (sim,) = servos.sims.values()
    return sim


def near(joints: Mapping[str, float]) -> dict[str, object]:
    return {n: pytest.approx(v, abs=DEG) for n, v in joints.items()}


def goal_ticks(sim: SimServoBus, servo_id: int) -> int:
    return int.from_bytes(sim.servos[servo_id].read(116, 4)[1], "little", signed=True)


# ---------------------------------------------------------------------- the subset rule
SUBSET_START = {"light_theta": 0.0, "camera_theta": 70.0, "camera_phi": 0.0}
SUBSET_TARGET = {"light_theta": 80.0, "camera_theta": 70.0, "camera_phi": 40.0}
"""Together, camera_phi swings the camera out of the light's way in time; the light swinging
alone (camera_phi missed the sync write) goes through the camera at θ 70°."""


def test_a_sync_write_one_axis_alone_would_collide_is_refused_then_routed() -> None:
    with rig_servos(SteppedClock()) as servos:
        motion, planner, sim = servos.motion, servos.planner, only_sim(servos)
        routed_move(motion, planner, SUBSET_START)
        before = sim.instructions["SYNC_WRITE"]
        moving = {n: SUBSET_TARGET[n] for n in ("light_theta", "camera_phi")}
        with pytest.raises(CollisionError) as refused:
            motion.move_to(moving)
        line = str(refused.value)
        assert "\n" not in line and line.startswith("refused move of light_theta and camera_phi: ")
        assert "moving light_theta alone (if camera_phi misses the sync write)" in line
        assert sim.instructions["SYNC_WRITE"] == before  # nothing sent
        routes: list[list[dict[str, float]]] = []
        assert routed_move(motion, planner, moving, routes.append) == near(SUBSET_TARGET)
        (legs,) = routes
        at = SUBSET_START
        for leg in legs:  # every leg safe, also for each subset of its axes moving alone
            planner.check_move(at, leg)
            at = leg
        assert servos.true_joints() == near(SUBSET_TARGET)


@pytest.mark.collides
def test_without_the_subset_rule_a_missed_sync_write_collides() -> None:
    """What the rule prevents: the same sync write, unguarded, with camera_phi deaf to it."""
    with rig_servos(SteppedClock()) as servos:
        routed_move(servos.motion, servos.planner, SUBSET_START)
        sim, axes = only_sim(servos), servos.axes
        sim.sim_drop_next(CAMERA_PHI, ["SYNC_WRITE"])
        bus = servos.buses["main"]
        with bus.permit_goals():  # bypassing the guard, as a careless client would
            bus.write_goals({axes[n].servo_id: axes[n].deg_to_ticks(v)
                             for n, v in SUBSET_TARGET.items()})
        bus.ping(LIGHT)  # the sync write has been acted on
        servos.clock.sleep(2.0)
        (hit,) = sim.sim_collisions()
        assert hit.axes == ("light_theta",)


# ---------------------------------------------------------------------- guarded braking
class BrakingGuard(RecordingGuard):
    """Allows moves; refuses any braking goal away from where the axes stand while ``refuse``."""

    refuse = False

    def check_move(self, start_deg: Mapping[str, float], targets_deg: Mapping[str, float]) -> None:
        super().check_move(start_deg, targets_deg)
        if self.refuse and any(abs(v - start_deg[n]) > 1e-9 for n, v in targets_deg.items()):
            raise CollisionError("refused move of a1: braking there would bring the arms together")


@pytest.mark.parametrize("refuse", [False, True])
def test_a_braking_goal_the_guard_refuses_is_not_written(refuse: bool) -> None:
    clock = SteppedClock()
    with SimServoBus([1, 2], clock=clock) as sim, ServoBus(sim.port) as bus:
        guard = BrakingGuard()
        axes = [Axis(f"a{i}", i, min_deg=-90, max_deg=90, profile_velocity=120,
                     profile_acceleration=30) for i in (1, 2)]
        mc = MotionController(axes, bus, guard=guard, sleep=clock.sleep, monotonic=clock.now)
        mc.apply_profiles()
        mc.set_torque(True)
        with bus.permit_goals():
            bus.write_goals({1: 3000})  # a move under way (its guard is not the point here)
        bus.ping(1)
        clock.advance(0.1)  # mid-move, at speed
        guard.refuse = refuse
        stopped = mc.stop()
        present, braking = guard.calls[-1]  # the guard saw every axis' braking goal
        assert braking["a1"] > present["a1"] + 1.0  # braking runs on past the present position
        written = goal_ticks(sim, 1)
        if refuse:  # stopped where it stood instead: goal := present
            assert stopped["a1"] == pytest.approx(present["a1"], abs=1e-9)
            assert written == axes[0].deg_to_ticks(present["a1"])
        else:
            assert stopped["a1"] == pytest.approx(braking["a1"], abs=1e-9)
            assert written == axes[0].deg_to_ticks(braking["a1"])


# ---------------------------------------------------------------------- partial moves
PARTIAL_START = {"light_theta": -45.0, "camera_theta": 45.0, "camera_phi": -60.0}
PARTIAL_TARGET = {"light_theta": 45.0, "camera_theta": 45.0, "camera_phi": 60.0}
"""Safe as one sync write, and for each axis alone; but once the light stands at 45° (camera_phi
missed the write), swinging camera_phi across goes through the light."""
SLOW_LIGHT = ("delay:id=1,ms=15",)
"""On a clock at 100 × host time, the light's replies 15 ms (host) late: 1.5 s of rig time
pass before the read-back shows the lost goal, so the light finishes its swing alone."""


def record_routes(planner: Planner, monkeypatch: pytest.MonkeyPatch) -> list[dict[str, float]]:
    """The start pose of every route the planner is asked for from now on."""
    starts: list[dict[str, float]] = []
    original = planner.route

    def route(current: Mapping[str, float], target: Mapping[str, float]) -> list:
        starts.append(dict(current))
        return original(current, target)

    monkeypatch.setattr(planner, "route", route)
    return starts


def test_a_partial_move_is_rerouted_from_the_read_back_pose(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with rig_servos(SimClock(100.0), SLOW_LIGHT) as servos:
        motion, planner, sim = servos.motion, servos.planner, only_sim(servos)
        routed_move(motion, planner, PARTIAL_START)
        planner.check_move(PARTIAL_START, PARTIAL_TARGET)  # one guarded sync write
        starts = record_routes(planner, monkeypatch)
        routes: list[list[dict[str, float]]] = []
        sim.sim_drop_next(CAMERA_PHI, ["SYNC_WRITE"])
        assert routed_move(motion, planner, PARTIAL_TARGET, routes.append) == near(PARTIAL_TARGET)
        assert sim.wire_stats[CAMERA_PHI]["instruction", "dropped", "SYNC_WRITE"] == 1
        first, replanned = starts  # the direct move, then a route from where the axes stopped
        assert first == near(PARTIAL_START)
        assert replanned == near({**PARTIAL_START, "light_theta": 45.0})
        (legs,) = routes  # printed (console) before the route moved
        assert len(legs) > 1 and legs[-1] == PARTIAL_TARGET
        assert servos.true_joints() == near(PARTIAL_TARGET)


def test_a_partial_move_with_no_route_from_where_it_stopped_is_one_line(
        monkeypatch: pytest.MonkeyPatch) -> None:
    with rig_servos(SimClock(100.0), SLOW_LIGHT) as servos:
        motion, planner, sim = servos.motion, servos.planner, only_sim(servos)
        routed_move(motion, planner, PARTIAL_START)
        direct_only = planner.router.route

        def no_detours(a, b):  # noqa: ANN001, ANN202 - the router, minus every detour
            legs = direct_only(a, b)
            return legs if legs is not None and len(legs) == 1 else None

        monkeypatch.setattr(planner.router, "route", no_detours)
        sim.sim_drop_next(CAMERA_PHI, ["SYNC_WRITE"])
        with pytest.raises(CollisionError) as refused:
            routed_move(motion, planner, PARTIAL_TARGET)
        line = str(refused.value)
        assert "\n" not in line
        assert line.startswith("after a partial move (camera_phi missed the goal write; all axes "
                               "stopped at light_theta 45.0°")
        assert "refused move of camera_phi: moving camera_phi brings the arms" in line
        assert "no route round it exists inside the joint limits" in line
        stopped = {**PARTIAL_START, "light_theta": 45.0}
        assert servos.true_joints() == near(stopped)  # nothing moved after the stop
