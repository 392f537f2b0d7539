"""The operator's console (API and ``gonio`` commands) on the simulated rig and on pty ports.

A rig file with ``simulated = true`` starts the servo simulator in-process. For the "real
hardware" paths (wrong port, wrong baud rate, missing servos, latency timer) the simulator is
started here on its own pty and a rig file names that port with ``simulated = false``, so the
console opens it exactly like a USB adapter.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

import acquisition.devices.servos as devices_mod
from acquisition.cli import main
from acquisition.devices.console import AxisStatus, format_status, open_console, scan_port
from acquisition.devices.health import ServoHealthError
from acquisition.devices.servos import LatencyWarning
from drivers.dynamixel import OverloadError, TorqueOffError
from drivers.errors import CollisionError, CommunicationError, ConfigError, LimitError
from simulators.dynamixel import SimServoBus

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
RIG = EXAMPLES / "rig-sim.toml"
PARK = {"light_theta": 0.0, "camera_theta": 45.0, "camera_phi": 0.0}
TICK_DEG = 360 / 4096


def goal_ticks(bus: SimServoBus, sid: int) -> int:
    return int.from_bytes(bus.servos[sid].read(116, 4)[1], "little", signed=True)


def rig_on_port(folder: Path, port: str, baud: int = 57600) -> Path:
    """The example rig, its bus on ``port`` as real hardware."""
    text = RIG.read_text().replace('port = "sim"', f'port = "{port}"')
    text = text.replace("simulated = true", "simulated = false")
    text = text.replace("baud = 57600", f"baud = {baud}")
    path = folder / "rig-port.toml"
    path.write_text(text)
    return path


@pytest.fixture
def pty_bus() -> Iterator[SimServoBus]:
    """Servos 1–3 at 1 Mbaud on their own pty, deaf at any other rate."""
    with SimServoBus([1, 2, 3], baud=1_000_000, strict_baud=True,
                     positions={1: 2048, 2: 1536, 3: 2048}) as bus:
        yield bus


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gonio: error: "), err
    assert "Traceback" not in err
    return lines[0]


# ---------------------------------------------------------------------- API on the sim rig
def test_status_starts_at_the_park_pose(sims: list[SimServoBus]) -> None:
    with open_console(RIG) as con:
        rows = con.status()
    assert [r.axis for r in rows] == list(PARK)
    for r in rows:
        assert r.position_deg == pytest.approx(PARK[r.axis], abs=TICK_DEG)
        assert r.goal_deg == pytest.approx(PARK[r.axis], abs=TICK_DEG)
        assert not r.moving and r.torque_on and r.errors == ()
        assert 25 <= r.temperature_c <= 40 and r.voltage_v == pytest.approx(12.0)
    assert [r.servo_id for r in rows] == [1, 2, 3]


def test_jog_move_home_park_follow_the_guard(sims: list[SimServoBus]) -> None:
    with open_console(RIG) as con:
        (bus,) = sims
        got = con.jog("camera_phi", 25.0)
        assert got == {"camera_phi": pytest.approx(25.0, abs=TICK_DEG)}
        true = con.servos.true_joints()
        assert true["camera_phi"] == pytest.approx(25.0, abs=TICK_DEG)
        assert true["light_theta"] == pytest.approx(0.0, abs=TICK_DEG)  # the others held

        joints = con.move_pose(30.0, 45.0, 180.0)
        pose = con.servos.planner.kinematics.forward(con.positions())
        assert (pose.theta_i, pose.theta_r) == (pytest.approx(30.0, abs=0.1),
                                                pytest.approx(45.0, abs=0.1))
        assert abs(pose.delta_phi) == pytest.approx(180.0, abs=0.1)
        assert set(joints) == set(PARK)

        # Both arms at the zenith: refused by the guard; nothing sent.
        goals = {i: goal_ticks(bus, i) for i in (1, 2, 3)}
        with pytest.raises(CollisionError, match=r"refused move"):
            con.move_joints(dict.fromkeys(PARK, 0.0))
        assert {i: goal_ticks(bus, i) for i in (1, 2, 3)} == goals
        # Home is the park pose on a rig file without [home]; one axis goes to its home angle.
        assert con.home(["camera_phi"]) == {"camera_phi": pytest.approx(0.0, abs=TICK_DEG)}
        goals = {i: goal_ticks(bus, i) for i in (1, 2, 3)}

        # Beyond the soft limit of camera_phi (±179°), or below the horizon: refused, nothing
        # sent.
        with pytest.raises(LimitError, match=r"camera_phi=200.000° outside \[-179, 179\]"):
            con.jog("camera_phi", 200.0)
        with pytest.raises(LimitError, match="elevation"):
            con.jog("camera_theta", 60.0)
        assert {i: goal_ticks(bus, i) for i in (1, 2, 3)} == {**goals, 3: 2048}
        with pytest.raises(ConfigError, match="no axis 'nope'"):
            con.jog("nope", 1.0)

        parked = con.park()
        assert parked == {k: pytest.approx(v, abs=TICK_DEG) for k, v in PARK.items()}


def test_torque_off_refuses_moves_and_reboot_clears_an_overload(sims: list[SimServoBus]) -> None:
    with open_console(RIG) as con:
        (bus,) = sims
        con.set_torque(False, ["camera_phi"])
        with pytest.raises(TorqueOffError, match="gonio torque on"):
            con.jog("camera_phi", 5.0)
        con.set_torque(True)
        con.jog("camera_phi", 5.0)

        bus.servos[2].sim_trip(0x20)  # an overload, as if the arm were blocked
        row = next(r for r in con.status() if r.axis == "camera_theta")
        assert row.errors == ("overload",) and not row.torque_on
        with pytest.raises(OverloadError, match=r"axis 'camera_theta'.*gonio reboot camera_theta"):
            con.jog("camera_phi", 5.0)
        with pytest.raises(OverloadError):
            con.set_torque(True)

        row = con.reboot("camera_theta")
        assert row.errors == () and not row.torque_on
        con.set_torque(True)
        assert con.jog("camera_theta", -5.0) == {"camera_theta": pytest.approx(40.0, abs=0.1)}


def test_console_refuses_a_move_when_the_supply_is_out_of_range() -> None:
    with open_console(RIG, sim_faults=["voltage:id=3,volts=15.0"]) as con:
        with pytest.raises(ServoHealthError, match=r"axis 'camera_phi' \(servo 3\) supply 15.0 V"):
            con.jog("camera_phi", 5.0)
        assert con.positions()["camera_phi"] == pytest.approx(0.0, abs=TICK_DEG)


def test_format_status_columns() -> None:
    rows = [AxisStatus("light_theta", 1, -29.97, -30.0, True, 41, 11.7, (), True),
            AxisStatus("camera_theta", 2, 45.0, 45.0, False, 33, 12.0, ("overload",), False)]
    lines = format_status(rows).splitlines()
    assert lines[0].split()[:3] == ["axis", "ID", "position"]
    assert lines[1].split() == ["light_theta", "1", "-29.97", "-30.00", "yes", "41", "11.7",
                                "on", "-"]
    assert lines[2].split() == ["camera_theta", "2", "45.00", "45.00", "no", "33", "12.0",
                                "off", "overload"]


# ---------------------------------------------------------------------- CLI on the sim rig
def test_cli_status_and_moves(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["status", "--rig", str(RIG)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 5 and out[2].split()[:4] == ["camera_theta", "2", "45.00", "45.00"]
    assert out[4] == "pose: θi 0.00°  θr 45.00°  Δφ - (a direction is at the normal)"

    assert main(["jog", "camera_phi", "-20", "--rig", str(RIG)]) == 0
    assert capsys.readouterr().out.strip() == "camera_phi -20.04°  (read back)"
    assert main(["move", "--rig", str(RIG), "--theta-i", "30", "--theta-r", "30",
                 "--delta-phi", "180"]) == 0
    assert "light_theta -29.97°" in capsys.readouterr().out
    assert main(["home", "camera_phi", "--rig", str(RIG)]) == 0
    assert main(["park", "--rig", str(RIG)]) == 0
    assert main(["torque", "off", "--rig", str(RIG)]) == 0
    assert "torque off: light_theta, camera_theta, camera_phi" in capsys.readouterr().out
    assert main(["reboot", "camera_phi", "--rig", str(RIG)]) == 0
    assert "rebooted axis 'camera_phi'" in capsys.readouterr().out


def test_cli_reports_an_overload_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    fault = ["--sim-fault", "overload:id=2,after=0"]
    assert main(["status", "--rig", str(RIG), *fault]) == 1  # a hardware error is shown
    table = capsys.readouterr().out.splitlines()
    assert table[2].split()[-2:] == ["off", "overload"]
    assert main(["jog", "camera_theta", "5", "--rig", str(RIG), *fault]) != 0
    line = one_error_line(capsys.readouterr().err)
    assert "axis 'camera_theta'" in line and "overload" in line
    assert "gonio reboot camera_theta" in line


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["home", "nope"], "no axis 'nope'"),
        (["jog", "camera_phi", "200"], "camera_phi=200.000° outside [-179, 179]°"),
        (["jog", "nope", "1"], "no axis 'nope'"),
        (["move", "--theta-i", "89", "--theta-r", "10", "--delta-phi", "0"], "rejected"),
    ],
)
def test_cli_refusals_are_one_line(argv: list[str], message: str,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*argv, "--rig", str(RIG)]) != 0
    assert message in one_error_line(capsys.readouterr().err)


# ---------------------------------------------------------------------- ports and baud rates
def test_scan_finds_the_simulated_rig_at_its_baud_only(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["scan", "--rig", str(RIG), "--ids", "1-4", "--bauds", "1000000", "57600"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    assert out[0].endswith("at 57600 baud: ID 1 (model 1020), ID 2 (model 1020), "
                           "ID 3 (model 1020)")


def test_scan_a_port(pty_bus: SimServoBus, capsys: pytest.CaptureFixture[str]) -> None:
    result = scan_port(pty_bus.port, bauds=[57600, 1_000_000], ids=[1, 2, 3, 9])
    assert result.found == {1_000_000: {1: 1020, 2: 1020, 3: 1020}}
    assert main(["scan", "--port", pty_bus.port, "--ids", "2", "--bauds", "1000000"]) == 0
    assert capsys.readouterr().out.strip() == f"{pty_bus.port} at 1000000 baud: ID 2 (model 1020)"


def test_unreachable_port_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = rig_on_port(tmp_path, "/dev/ttyUSB-gonio-absent")
    assert main(["status", "--rig", str(rig)]) != 0
    line = one_error_line(capsys.readouterr().err)
    assert "cannot open servo port /dev/ttyUSB-gonio-absent (bus 'main')" in line
    assert main(["scan", "--port", "/dev/ttyUSB-gonio-absent", "--ids", "1"]) != 0
    assert "cannot open servo port" in one_error_line(capsys.readouterr().err)
    with pytest.raises(CommunicationError), open_console(rig):
        pass


def test_wrong_baud_rate_names_the_right_one(pty_bus: SimServoBus, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    rig = rig_on_port(tmp_path, pty_bus.port, baud=57600)
    assert main(["status", "--rig", str(rig)]) != 0
    line = one_error_line(capsys.readouterr().err)
    assert "no servo answers" in line and "at 57600 baud" in line
    assert "ID 1, 2, 3 answer at 1000000 baud: set baud = 1000000 in [buses.main]" in line


def test_missing_servo_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with SimServoBus([1, 2], baud=57600, strict_baud=True) as bus:
        rig = rig_on_port(tmp_path, bus.port)
        assert main(["status", "--rig", str(rig)]) != 0
    line = one_error_line(capsys.readouterr().err)
    assert "no answer from servo ID 3 (axis 'camera_phi')" in line and "gonio scan" in line


def test_high_latency_timer_warns_once(pty_bus: SimServoBus, tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    sysfs = tmp_path / "usb-serial"
    tty = Path(pty_bus.port).name
    (sysfs / tty).mkdir(parents=True)
    (sysfs / tty / "latency_timer").write_text("16\n")
    monkeypatch.setattr(devices_mod, "LATENCY_SYSFS", sysfs)
    rig = rig_on_port(tmp_path, pty_bus.port, baud=1_000_000)

    with pytest.warns(LatencyWarning, match="latency timer is 16 ms"), open_console(rig) as con:
        assert len(con.status()) == 3
    assert main(["status", "--rig", str(rig)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: warning: servo port")
    assert "set it to 1 ms" in err[0]

    (sysfs / tty / "latency_timer").write_text("1\n")
    assert main(["status", "--rig", str(rig)]) == 0
    assert capsys.readouterr().err == ""
