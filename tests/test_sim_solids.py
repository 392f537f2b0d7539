"""The simulator's solid parts: capsule geometry, contact dynamics, collision records.

Geometry is checked against brute force; contact dynamics through the unmodified
``dynamixel_sdk`` (PortHandler, PacketHandler, GroupSyncWrite) on the pty of
:func:`simulators.dynamixel.serve_rig`, on a stepped clock so that stall times are exact.
"""

from __future__ import annotations

import logging
import math
import random
from pathlib import Path

import numpy as np
import pytest
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler
from guards import RecordingGuard

from drivers.dynamixel import Axis, MotionController, OverloadError, ServoBus
from simulators.clock import SteppedClock
from simulators.dynamixel import SimServoBus, serve_rig
from simulators.rig_solids import (
    DEFAULT_ARM_RADIUS_M,
    KINDS,
    Capsule,
    SolidAxis,
    SolidRig,
    closest_points,
    load_rig_toml,
    pose_deg_of,
    solid_rig_from_toml,
)

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
RIG_SIM = EXAMPLES / "rig-sim.toml"
RIG_COAXIAL = EXAMPLES / "rig-coaxial-sim.toml"
PH = PacketHandler(2.0)
GOAL, MOVING, CURRENT, POSITION, HW_ERROR, TORQUE = 116, 122, 126, 132, 70, 64
OVERLOAD = 0x20
ALERT = 0x80
TICKS_PER_DEG = 4096 / 360


# ---------------------------------------------------------------------- geometry
BRUTE_N = 151


def brute_distance(p1, q1, p2, q2, n: int = BRUTE_N) -> float:
    s = np.linspace(0.0, 1.0, n)[:, None]
    a = p1 + s * (q1 - p1)
    b = p2 + s * (q2 - p2)
    return float(np.min(np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)))


def test_segment_distance_matches_brute_force_sampling():
    rng = random.Random(1)
    for _ in range(300):
        pts = [np.array([rng.uniform(-1, 1) for _ in range(3)]) for _ in range(4)]
        if rng.random() < 0.2:  # parallel segments
            pts[3] = pts[2] + rng.uniform(-2, 2) * (pts[1] - pts[0])
        if rng.random() < 0.1:  # a point
            pts[1] = pts[0].copy()
        d, c1, c2 = closest_points(*(tuple(p) for p in pts))
        brute = brute_distance(*pts)
        lengths = np.linalg.norm(pts[1] - pts[0]) + np.linalg.norm(pts[3] - pts[2])
        assert d <= brute + 1e-12  # never worse than any sampled pair
        assert d >= brute - lengths / (BRUTE_N - 1)  # and not better than the grid allows
        assert math.dist(c1, c2) == pytest.approx(d, abs=1e-12)  # the points realise it


def test_segment_distance_special_cases():
    # Crossing segments touch; collinear disjoint ones are their end gap apart.
    assert closest_points((-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0))[0] == pytest.approx(0.0)
    assert closest_points((0, 0, 0), (1, 0, 0), (3, 0, 0), (5, 0, 0))[0] == pytest.approx(2.0)
    # Two rays from the origin 10° apart, as the arms are: the nearer start point to the other.
    a = math.radians(10)
    d, _, c2 = closest_points((0.4, 0, 0), (0.52, 0, 0),
                              (0.48 * math.cos(a), 0.48 * math.sin(a), 0),
                              (0.625 * math.cos(a), 0.625 * math.sin(a), 0))
    assert d == pytest.approx(0.48 * math.sin(a))
    assert c2 == pytest.approx((0.48 * math.cos(a), 0.48 * math.sin(a), 0))


def test_arms_default_to_the_rig_parsers_numbers():
    rig = solid_rig_from_toml(load_rig_toml(RIG_SIM))  # no [arms] table
    assert rig.arms["light"] == Capsule(DEFAULT_ARM_RADIUS_M["light"], 0.8 * 0.5, 0.5 + 0.02)
    assert rig.arms["camera"] == Capsule(0.025, 0.8 * 0.6, 0.6 + 0.025)
    coax = solid_rig_from_toml(load_rig_toml(RIG_COAXIAL))  # explicit [arms]
    assert coax.arms["light"] == Capsule(0.03, 0.42, 0.55)
    assert coax.axes["stage_tilt"] == SolidAxis(3, 2048, 1, min_deg=-85, max_deg=85, bus="main")


def test_the_same_numbers_as_gonio_states():
    # The simulator duplicates gonio's [arms] defaults on purpose; they must not drift apart.
    from acquisition.config.rig import load_rig

    for path in (RIG_SIM, RIG_COAXIAL):
        theirs = load_rig(path).arms
        ours = solid_rig_from_toml(load_rig_toml(path)).arms
        for arm in ("light", "camera"):
            mine, gonio = ours[arm], getattr(theirs, arm)
            assert (mine.radius_m, mine.from_m, mine.to_m) == pytest.approx(
                (gonio.radius_m, gonio.from_m, gonio.to_m))


@pytest.mark.parametrize("kind", ["out-of-plane-arcs", "coaxial-arms"])
def test_inverse_candidates_realise_the_pose(kind):
    kin = KINDS[kind]
    rng = random.Random(2)
    for _ in range(200):
        pose = (rng.uniform(0, 80), rng.uniform(0, 80), rng.uniform(-179, 179))
        cands = kin.candidates(pose)
        assert cands, pose
        for joints in cands:
            got = pose_deg_of(kin, joints)
            assert got[:2] == pytest.approx(pose[:2], abs=1e-6)
            assert math.remainder(got[2] - pose[2], 360) == pytest.approx(0, abs=1e-6)


def test_park_pose_is_the_white_reference_with_the_arms_apart():
    for path, expected in ((RIG_SIM, {"light_theta": 0, "camera_theta": 45, "camera_phi": 0}),
                           (RIG_COAXIAL, {"light_azimuth": 0, "camera_azimuth": 45,
                                          "stage_tilt": 0, "stage_rotation": 0})):
        rig = solid_rig_from_toml(load_rig_toml(path))
        park = rig.park_deg()
        assert park == pytest.approx(expected, abs=1e-5)
        assert rig.gap_m(park) > 0.1


# ---------------------------------------------------------------------- contact dynamics
def open_port(path: str, baud: int = 57600) -> PortHandler:
    port = PortHandler(path)
    assert port.openPort() and port.setBaudRate(baud)
    return port


def ticks(deg: float, zero: int = 2048) -> int:
    return round(zero + deg * TICKS_PER_DEG)


def sync_goals(port: PortHandler, goals: dict[int, int]) -> None:
    writer = GroupSyncWrite(port, PH, GOAL, 4)
    for sid, goal in goals.items():
        assert writer.addParam(sid, list(goal.to_bytes(4, "little", signed=True)))
    assert writer.txPacket() == COMM_SUCCESS
    # A SYNC_WRITE has no reply: one round trip makes sure the bus has acted on it before the
    # test moves the stepped clock on.
    assert PH.ping(port, next(iter(goals)))[1] == COMM_SUCCESS


def read(port: PortHandler, sid: int, address: int, size: int) -> tuple[int, int]:
    """(value, error byte) of one read; the transfer itself must succeed (retried twice after a
    timeout, as a polling client does: on a loaded host the simulator may compute the arms'
    contact past the SDK's ~34 ms packet timeout)."""
    fn = {1: PH.read1ByteTxRx, 2: PH.read2ByteTxRx, 4: PH.read4ByteTxRx}[size]
    for _ in range(3):
        value, result, error = fn(port, sid, address)
        if result != COMM_RX_TIMEOUT:
            break
    assert result == COMM_SUCCESS
    if size == 4 and value >= 2**31:
        value -= 2**32
    return value, error


def torque_on(port: PortHandler, ids) -> None:
    for sid in ids:
        assert PH.write1ByteTxRx(port, sid, 9, 0) == (COMM_SUCCESS, 0)  # no return delay
        assert PH.write1ByteTxRx(port, sid, TORQUE, 1) == (COMM_SUCCESS, 0)


@pytest.fixture
def clock():
    return SteppedClock()


@pytest.fixture
def out_of_plane(clock):
    with serve_rig(RIG_SIM, clock=clock, wire_time=False) as rig:  # contact physics alone
        port = open_port(rig.port)
        torque_on(port, (1, 2, 3))
        yield rig, port
        port.closePort()


#: light_theta where its capsule touches the camera's at camera_theta = 45°, camera_phi = 0:
#: the camera capsule's start (0.48 m) is 0.045 m (the radii) from the light's axis.
CONTACT_DEG = 45.0 - math.degrees(math.asin(0.045 / 0.48))


@pytest.mark.collides
def test_light_arm_driven_into_the_camera_stalls_at_contact_then_trips(out_of_plane, clock):
    rig, port = out_of_plane
    sync_goals(port, {1: ticks(60.0)})
    clock.advance(0.5)
    (hit,) = rig.sim_collisions()
    assert hit.axes == ("light_theta",) and hit.servo_ids == (1,)
    assert hit.positions_deg["light_theta"] == pytest.approx(CONTACT_DEG, abs=1e-4)
    assert hit.positions_deg["camera_theta"] == pytest.approx(45.0)
    assert hit.positions_ticks["light_theta"] == pytest.approx(ticks(0) + CONTACT_DEG * TICKS_PER_DEG,
                                                               abs=0.01)
    assert math.dist(hit.light_point_m, hit.camera_point_m) == pytest.approx(0.045, abs=1e-6)
    # No profile written: the servo runs at its Velocity Limit (200 × 0.229 rev/min) at once.
    assert hit.time_s == pytest.approx(CONTACT_DEG / (200 * 0.229 * 6), abs=1e-6)
    # Stalled, not yet tripped: held at contact, Moving, drawing the stall current.
    position, error = read(port, 1, POSITION, 4)
    assert position == round(ticks(0) + CONTACT_DEG * TICKS_PER_DEG) and error == 0
    assert read(port, 1, MOVING, 1) == (1, 0)
    assert read(port, 1, CURRENT, 2)[0] > 800
    assert read(port, 1, HW_ERROR, 1) == (0, 0)
    clock.advance(hit.time_s + 1.0 - clock.now() + 1e-3)  # past stall_trip_s (1 s)
    # Overload latched, Alert on every status packet of servo 1, Shutdown turned torque off.
    assert read(port, 1, HW_ERROR, 1) == (OVERLOAD, ALERT)
    assert read(port, 1, TORQUE, 1) == (0, ALERT)
    assert read(port, 1, MOVING, 1) == (0, ALERT)
    assert PH.ping(port, 1)[2] == ALERT
    assert read(port, 2, HW_ERROR, 1) == (0, 0)  # the camera was pushed, not pushing
    assert read(port, 1, POSITION, 4)[0] == position
    assert len(rig.sim_collisions()) == 1
    # The existing reboot path clears it; moving away from the contact works.
    assert PH.reboot(port, 1)[0] == COMM_SUCCESS
    assert read(port, 1, HW_ERROR, 1) == (0, 0)
    torque_on(port, (1,))
    sync_goals(port, {1: ticks(0.0)})
    clock.advance(1.0)
    assert read(port, 1, POSITION, 4) == (ticks(0.0), 0)
    assert len(rig.sim_collisions()) == 1


@pytest.mark.collides
def test_moving_away_before_the_trip_clears_the_stall(out_of_plane, clock):
    rig, port = out_of_plane
    sync_goals(port, {1: ticks(60.0)})
    clock.advance(0.6)
    assert read(port, 1, MOVING, 1) == (1, 0)
    sync_goals(port, {1: ticks(10.0)})  # back off before stall_trip_s
    clock.advance(2.0)
    assert read(port, 1, HW_ERROR, 1) == (0, 0)
    assert read(port, 1, POSITION, 4) == (ticks(10.0), 0)
    assert read(port, 1, MOVING, 1) == (0, 0)
    assert len(rig.sim_collisions()) == 1


@pytest.mark.collides
def test_a_stalled_arm_follows_when_the_other_moves_away(out_of_plane, clock):
    rig, port = out_of_plane
    sync_goals(port, {1: ticks(60.0)})
    clock.advance(0.5)
    assert read(port, 1, MOVING, 1) == (1, 0)  # stalled against the camera
    sync_goals(port, {2: ticks(85.0, 1024)})  # the camera arm swings away, before the trip
    poll(port, clock, 2.0)  # a polling client: one long jump may outlast a packet timeout
    assert read(port, 1, POSITION, 4) == (ticks(60.0), 0)  # the light went on to its goal
    assert read(port, 1, HW_ERROR, 1) == (0, 0)
    assert len(rig.sim_collisions()) == 1


def poll(port: PortHandler, clock: SteppedClock, seconds: float, ids=(1, 2, 3)) -> None:
    """Let ``seconds`` of device time pass as a polling client does: 50 ms per read."""
    for _ in range(round(seconds / 0.05)):
        clock.advance(0.05)
        for sid in ids:
            read(port, sid, POSITION, 4)


@pytest.mark.collides
def test_only_the_servo_pushing_into_the_contact_stalls_and_follows(out_of_plane, clock):
    rig, port = out_of_plane
    # The camera arm moves away slowly (20 × 0.229 rev/min = 27.5 °/s) while the light, ten
    # times faster, catches up with it: the light stalls and follows it, the camera goes on.
    assert PH.write4ByteTxRx(port, 2, 112, 20) == (COMM_SUCCESS, 0)
    sync_goals(port, {1: ticks(60.0), 2: ticks(85.0, 1024)})
    poll(port, clock, 0.3)
    (hit,) = rig.sim_collisions()
    assert hit.axes == ("light_theta",)
    assert read(port, 2, MOVING, 1) == (1, 0) and read(port, 2, CURRENT, 2)[0] < 800
    assert read(port, 1, CURRENT, 2)[0] > 800  # still pushing
    joints = rig.sim_true_joints_deg()
    one_tick_m = 0.5 * 2 * math.pi / 4096  # the light's encoder tick at the contact (~0.5 m)
    assert 0 <= rig.solid_rig.gap_m(joints) <= one_tick_m  # touching, to a tick
    assert joints["light_theta"] > hit.positions_deg["light_theta"] + 3  # it followed
    # The light's goal is clear once the camera is past 65.4° (~0.8 s): the light gets there
    # within its stall time, so nothing trips.
    poll(port, clock, 1.7)
    assert read(port, 2, POSITION, 4) == (ticks(85.0, 1024), 0)
    assert read(port, 1, POSITION, 4) == (ticks(60.0), 0)
    assert [read(port, sid, HW_ERROR, 1) for sid in (1, 2)] == [(0, 0), (0, 0)]
    assert len(rig.sim_collisions()) == 1  # one contact episode


@pytest.mark.collides
def test_pushing_a_retreating_arm_for_the_stall_time_trips(out_of_plane, clock):
    rig, port = out_of_plane
    assert PH.write4ByteTxRx(port, 2, 112, 20) == (COMM_SUCCESS, 0)
    sync_goals(port, {1: ticks(80.0), 2: ticks(85.0, 1024)})  # the light wants past the camera
    poll(port, clock, 0.3)
    (hit,) = rig.sim_collisions()
    poll(port, clock, hit.time_s + 0.95 - clock.now())
    assert read(port, 1, HW_ERROR, 1) == (0, 0)
    poll(port, clock, 0.1)  # 1 s of pushing in all, though it kept moving
    assert read(port, 1, HW_ERROR, 1) == (OVERLOAD, ALERT)
    assert read(port, 1, TORQUE, 1) == (0, ALERT)
    assert read(port, 2, HW_ERROR, 1) == (0, 0)


def test_arms_moving_past_each_other_with_room_to_spare_see_no_error(out_of_plane, clock):
    rig, port = out_of_plane
    # Camera 6° from the zenith in the y–z plane: the light's capsule passes 2.3 mm from it
    # (0.48 sin 6° − 0.045 m) when it sweeps through the zenith in the x–z plane.
    sync_goals(port, {1: ticks(-30.0), 2: ticks(6.0, 1024), 3: ticks(90.0)})
    clock.advance(1.5)
    sync_goals(port, {1: ticks(30.0)})
    for _ in range(30):
        clock.advance(0.05)
        assert all(read(port, sid, HW_ERROR, 1) == (0, 0) for sid in (1, 2, 3))
    assert read(port, 1, POSITION, 4) == (ticks(30.0), 0)
    assert rig.sim_collisions() == []
    assert rig.solid_rig.gap_m({"light_theta": 0, "camera_theta": 6, "camera_phi": 90}) == \
        pytest.approx(0.48 * math.sin(math.radians(6)) - 0.045)


@pytest.mark.collides
def test_a_pass_a_little_too_close_collides(out_of_plane, clock):
    rig, port = out_of_plane
    sync_goals(port, {1: ticks(-30.0), 2: ticks(5.0, 1024), 3: ticks(90.0)})  # 3.2 mm overlap
    clock.advance(1.5)
    sync_goals(port, {1: ticks(30.0)})
    clock.advance(1.0)
    (hit,) = rig.sim_collisions()
    assert hit.axes == ("light_theta",) and hit.positions_deg["light_theta"] < 0


@pytest.mark.collides
def test_coaxial_arms_driven_together_both_stall_while_the_stage_moves_on(clock):
    with serve_rig(RIG_COAXIAL, clock=clock) as rig:
        port = open_port(rig.port)
        torque_on(port, (1, 2, 3, 4))
        # Light 0° → 60°, camera 45° → −20°, same profile: they meet half-way. The tilt stage
        # moves at the same time and is no part of the contact.
        sync_goals(port, {1: ticks(60.0), 2: ticks(-20.0), 3: ticks(30.0)})
        clock.advance(0.5)
        (hit,) = rig.sim_collisions()
        assert set(hit.axes) == {"light_azimuth", "camera_azimuth"}
        half_gap = math.degrees(math.asin(0.065 / 0.5))  # radii 0.03 + 0.035 at 0.5 m
        light, camera = hit.positions_deg["light_azimuth"], hit.positions_deg["camera_azimuth"]
        assert camera - light == pytest.approx(half_gap, abs=1e-4)
        assert light == pytest.approx((45.0 - half_gap) / 2, abs=0.05)
        clock.advance(1.2)
        assert read(port, 1, HW_ERROR, 1) == (OVERLOAD, ALERT)
        assert read(port, 2, HW_ERROR, 1) == (OVERLOAD, ALERT)
        assert read(port, 3, POSITION, 4) == (ticks(30.0), 0)  # the stage arrived
        assert read(port, 3, HW_ERROR, 1) == (0, 0)
        port.closePort()


@pytest.mark.collides
def test_collisions_are_logged(out_of_plane, clock, caplog):
    rig, port = out_of_plane
    with caplog.at_level(logging.WARNING, logger="simulators.dynamixel.world"):
        sync_goals(port, {1: ticks(60.0)})
        clock.advance(0.6)
        rig.sim_collisions()
    assert "arms touched" in caplog.text and "light_theta (servo 1) stalled" in caplog.text


def test_serve_rig_serves_the_rigs_ids_baud_limits_and_park_pose(clock):
    with serve_rig(RIG_SIM, clock=clock) as rig:
        port = open_port(rig.port)
        assert [PH.ping(port, sid)[1:] for sid in (1, 2, 3)] == [(COMM_SUCCESS, 0)] * 3
        assert PH.ping(port, 4)[1] != COMM_SUCCESS
        assert read(port, 1, 8, 1)[0] == 1  # Baud Rate register: 57600
        assert read(port, 1, 52, 4)[0] == math.floor(ticks(0) - 87 * TICKS_PER_DEG)
        assert read(port, 1, 48, 4)[0] == math.ceil(ticks(0) + 87 * TICKS_PER_DEG)
        assert read(port, 2, 52, 4)[0] == 1024 and read(port, 3, 48, 4)[0] > 4000
        assert [read(port, sid, POSITION, 4)[0] for sid in (1, 2, 3)] == [2048, 1536, 2048]
        port.closePort()


def test_a_bare_bus_has_no_solid_parts(clock):
    with SimServoBus([1, 2, 3], clock=clock, positions={2: 1536}) as sim:
        port = open_port(sim.port)
        torque_on(port, (1,))
        sync_goals(port, {1: ticks(60.0)})
        clock.advance(1.5)
        assert read(port, 1, POSITION, 4) == (ticks(60.0), 0)
        assert sim.sim_collisions() == [] and sim.world is None
        port.closePort()


@pytest.mark.collides
def test_gonio_driver_without_a_guard_sees_the_overload(clock):
    """The referee catches what a permissive guard lets through."""
    rig_file = load_rig_toml(RIG_SIM)
    with serve_rig(rig_file, clock=clock) as rig, ServoBus(rig.port, 57600) as bus:
        axes = [Axis(name, a["id"], min_deg=a["min_deg"], max_deg=a["max_deg"],
                     zero_tick=a["zero_tick"], profile_velocity=a["profile_velocity"],
                     profile_acceleration=a["profile_acceleration"])
                for name, a in rig_file["axes"].items()]
        mc = MotionController(axes, bus, guard=RecordingGuard(), sleep=clock.sleep,
                              monotonic=clock.now)
        mc.apply_profiles()
        mc.set_torque(True)
        with pytest.raises(OverloadError, match="axis 'light_theta'"):
            mc.move_to({"light_theta": 60.0})
        (hit,) = rig.sim_collisions()
        assert hit.axes == ("light_theta",)


def test_solid_rig_rejects_missing_joints():
    from drivers.errors import ConfigError

    with pytest.raises(ConfigError, match="camera_phi"):
        SolidRig("out-of-plane-arcs", {"light_theta": SolidAxis(1), "camera_theta": SolidAxis(2)},
                 {"light": Capsule(0.02, 0.4, 0.5), "camera": Capsule(0.02, 0.4, 0.5)})


@pytest.mark.collides
def test_one_world_spans_a_rig_whose_arms_are_on_two_buses(clock):
    data = load_rig_toml(RIG_SIM)
    data["buses"]["arm2"] = {"port": "sim", "baud": 1_000_000, "simulated": True}
    for name in ("camera_theta", "camera_phi"):
        data["axes"][name]["bus"] = "arm2"
    with serve_rig(data, clock=clock) as rig:
        assert set(rig.ports) == {"main", "arm2"}
        light, camera = open_port(rig.ports["main"]), open_port(rig.ports["arm2"], 1_000_000)
        torque_on(light, (1,))
        sync_goals(light, {1: ticks(60.0)})
        clock.advance(0.5)
        assert read(light, 1, MOVING, 1) == (1, 0)
        assert read(camera, 2, POSITION, 4) == (1536, 0)
        (hit,) = rig.buses["arm2"].sim_collisions()
        assert hit.axes == ("light_theta",) and rig.sim_collisions() == [hit]
        light.closePort()
        camera.closePort()


def test_serve_rig_forever_prints_the_path_first_and_stops_on_sigterm():
    import signal
    import subprocess
    import sys

    code = ("from simulators.dynamixel import serve_rig_forever as s;"
            f"raise SystemExit(s({str(RIG_SIM)!r}, "
            "ready=lambda r: print(*r.ports.values(), sep='\\n', flush=True)))")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        port = open_port(proc.stdout.readline().strip())
        assert PH.ping(port, 3)[0] == 1020
        port.closePort()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()
