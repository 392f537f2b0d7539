"""The console as an instrument: ``gonio console`` (one connection, a script on stdin or a
terminal), the pose in ``status``, the rig file's ``[home]``, routes printed before a move,
and the light stage (no moving axes) refusing every console verb in one line."""

from __future__ import annotations

import io
import json
import os
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest
from referee import SIM_COLLISION_LOG

from acquisition.cli import main
from acquisition.cli.shell import ConsoleShell, history_path, readline_history
from acquisition.config.rig import load_rig
from acquisition.devices.console import open_console
from drivers.errors import ConfigError
from simulators.dynamixel import SimServoBus

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
RIG = EXAMPLES / "rig-sim.toml"
LIGHT_STAGE = EXAMPLES / "rig-lightstage-sim.toml"
PARK = {"light_theta": 0.0, "camera_theta": 45.0, "camera_phi": 0.0}
TICK_DEG = 360 / 4096
GONIO = [str(Path(sys.executable).with_name("gonio"))]


def shell(monkeypatch: pytest.MonkeyPatch, script: str, *extra: str, rig: Path = RIG) -> int:
    """``gonio console --rig RIG`` reading ``script`` from a (non-terminal) stdin."""
    monkeypatch.setattr(sys, "stdin", io.StringIO(script))
    return main(["console", "--rig", str(rig), *extra])


def rig_with(tmp_path: Path, home: str) -> Path:
    """The example simulated rig with ``home`` (TOML text) appended."""
    path = tmp_path / "rig-home.toml"
    path.write_text(RIG.read_text() + "\n" + home)
    return path


def status_rows(out: str) -> dict[str, list[str]]:
    """``{axis: cells}`` of every status table row in ``out`` (the last table wins)."""
    rows: dict[str, list[str]] = {}
    for line in out.splitlines():
        cells = line.split()
        if cells and cells[0] in PARK:
            rows[cells[0]] = cells
    return rows


def json_lines(out: str) -> list[dict]:
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gonio: error: "), err
    assert "Traceback" not in err
    return lines[0]


# ---------------------------------------------------------------------- the shell, scripted
def test_state_persists_between_lines_and_errors_do_not_end_the_session(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    script = ("jog camera_phi 10\n"
              "jog nope 1\n"            # an API error
              "jog camera_phi\n"        # a parser error
              "frobnicate\n"            # no such verb
              "  # a comment, then a blank line\n\n"
              "gonio jog camera_phi 5\n"  # pasted from an error message's advice
              "status\n")
    assert shell(monkeypatch, script) == 2  # the last failure's exit code
    captured = capsys.readouterr()
    rows = status_rows(captured.out)
    assert float(rows["camera_phi"][2]) == pytest.approx(15.0, abs=2 * TICK_DEG)
    assert float(rows["light_theta"][2]) == pytest.approx(0.0, abs=TICK_DEG)
    assert captured.out.splitlines()[0] == "camera_phi 10.02°  (read back)"  # no prompt noise
    assert "gonio>" not in captured.out
    errors = captured.err.strip().splitlines()
    assert len(errors) == 3 and all(e.startswith("gonio: error: ") for e in errors)
    assert "no axis 'nope'; the rig has light_theta, camera_theta, camera_phi" in errors[0]
    assert errors[1] == "gonio: error: jog: the following arguments are required: deg"
    assert "unknown command 'frobnicate'" in errors[2]


def test_a_clean_script_exits_zero_and_json_reports_the_pose(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    script = ("move --theta-i 30 --theta-r 30 --delta-phi 180\n"
              "status --json\n"
              "torque off camera_phi\n"
              "status --json\n")
    assert shell(monkeypatch, script) == 0
    out = capsys.readouterr().out
    first, second = json_lines(out)
    assert first["pose"]["theta_i_deg"] == pytest.approx(30.0, abs=0.1)
    assert first["pose"]["theta_r_deg"] == pytest.approx(30.0, abs=0.1)
    assert abs(first["pose"]["delta_phi_deg"]) == pytest.approx(180.0, abs=0.1)
    assert "torque off: camera_phi" in out
    torque = {r["axis"]: r["torque_on"] for r in second["axes"]}
    assert torque == {"light_theta": True, "camera_theta": True, "camera_phi": False}


def test_console_json_makes_every_line_json(monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    assert shell(monkeypatch, "jog camera_phi 10\nstatus\n", "--json") == 0
    jog, status = json_lines(capsys.readouterr().out)
    assert jog["joints_deg"]["camera_phi"] == pytest.approx(10.0, abs=TICK_DEG)
    assert jog["route"] == []  # a direct move
    assert status["pose"]["theta_r_deg"] == pytest.approx(45.0, abs=0.1)
    assert status["pose"]["delta_phi_deg"] is None  # the light is at the normal


def test_help_lists_the_verbs_and_help_verb_its_options(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    assert shell(monkeypatch, "help\nhelp move\njog -h\nquit\nstatus\n") == 0
    out = capsys.readouterr().out
    listed = [line.split()[0] for line in out.splitlines() if line.startswith("  ")]
    for verb in ("status", "scan", "jog", "move", "home", "park", "torque", "reboot", "help",
                 "quit"):
        assert verb in listed
    assert "usage: move" in out and "--theta-i" in out and "--delta-phi" in out
    assert "usage: jog" in out
    assert "position °" not in out  # quit ended the script before status


def test_the_shell_scans_its_own_buses(monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    assert shell(monkeypatch, "jog camera_phi 10\nscan --ids 1-3 --bauds 57600\nstatus\n") == 0
    out = capsys.readouterr().out
    assert "at 57600 baud: ID 1 (model 1020), ID 2 (model 1020), ID 3 (model 1020)" in out
    # the scan returned the bus to its rate, and the servos to their state
    assert float(status_rows(out)["camera_phi"][2]) == pytest.approx(10.0, abs=TICK_DEG)


def test_completion_offers_verbs_options_and_axis_names() -> None:
    with open_console(RIG) as con:
        sh = ConsoleShell(con, stdin=io.StringIO(""), stdout=io.StringIO())
        assert sh.completenames("j") == ["jog"]
        assert sh.completenames("") == ["status", "scan", "jog", "move", "home", "park",
                                        "torque", "reboot", "help", "quit", "exit"]
        assert sh.complete_jog("cam", "jog cam", 4, 7) == ["camera_theta", "camera_phi"]
        assert sh.complete_jog("", "jog camera_phi ", 15, 15) == []  # DEG is a number
        assert sh.complete_reboot("", "reboot ", 7, 7) == ["light_theta", "camera_theta",
                                                            "camera_phi"]
        assert sh.complete_torque("o", "torque o", 7, 8) == ["on", "off"]
        line = "torque off light_theta "
        assert sh.complete_torque("", line, len(line), len(line)) == ["camera_theta",
                                                                      "camera_phi"]
        assert sh.complete_home("", "home camera_phi ", 16, 16) == ["light_theta",
                                                                    "camera_theta"]
        assert sh.complete_move("--th", "move --th", 5, 9) == ["--theta-i", "--theta-r"]
        assert sh.complete_status("--j", "status --j", 7, 10) == ["--json"]
        assert sh.complete_help("t", "help t", 5, 6) == ["torque"]


def test_ctrl_c_during_a_move_stops_the_axes_and_returns_to_the_prompt(
        capsys: pytest.CaptureFixture[str]) -> None:
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when run as a background job
    with open_console(RIG) as con:
        motion = con.servos.motion
        real_sleep = motion._sleep
        presses: list[float] = []

        def sleep_then_ctrl_c(seconds: float) -> None:
            real_sleep(seconds)
            if not presses and motion.positions_deg(["camera_phi"])["camera_phi"] > 20.0:
                presses.append(time.monotonic())
                os.kill(os.getpid(), signal.SIGINT)  # as the terminal would, mid-move

        motion._sleep = sleep_then_ctrl_c
        sh = ConsoleShell(con, stdin=io.StringIO("jog camera_phi 120\nstatus --json\n"),
                          stdout=sys.stdout, interactive=False)
        assert sh.run() == 130
        captured = capsys.readouterr()
        assert presses, "the move never got past 20°"
        error = [line for line in captured.err.splitlines() if line.startswith("gonio: error")]
        assert len(error) == 1 and "interrupted: all axes stopped" in error[0]
        (status,) = json_lines(captured.out)  # the next line still ran
        row = next(r for r in status["axes"] if r["axis"] == "camera_phi")
        # The goal became the braking point, well short of 120°: the move was abandoned.
        assert 20.0 < row["position_deg"] <= row["goal_deg"] < 90.0
        assert row["torque_on"]
    assert signal.getsignal(signal.SIGINT) is before  # restored


def test_a_real_pipe_is_read_as_a_script(tmp_path: Path) -> None:
    out = subprocess.run(
        [*GONIO, "console", "--rig", str(RIG)], input="jog camera_phi 10\nstatus\n",
        capture_output=True, text=True, timeout=120, cwd=ROOT,
        env={**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")},
    )
    assert out.returncode == 0, out.stderr
    assert SIM_COLLISION_LOG not in out.stderr  # the child's simulator saw no contact
    lines = out.stdout.splitlines()
    assert lines[0] == "camera_phi 10.02°  (read back)"
    assert float(status_rows(out.stdout)["camera_phi"][2]) == pytest.approx(10.0, abs=TICK_DEG)
    assert lines[-1] == "pose: θi 0.00°  θr 45.00°  Δφ - (a direction is at the normal)"
    assert not (tmp_path / "state").exists()  # no history for a script


class PtyReader:
    """Reads a pty's primary side up to a marker, keeping what came after it for the next
    read: the child may write its reply and the next prompt in one burst, and one ``os.read``
    then returns both (dropping the rest would lose the prompt the next read waits for)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.pending = b""
        self.log = b""
        """Everything read so far."""

    def until(self, needle: bytes, timeout_s: float = 60.0) -> bytes:
        """Everything up to and including the first ``needle`` not read before."""
        deadline = time.monotonic() + timeout_s
        while needle not in self.pending:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                raise AssertionError(f"never saw {needle!r} in {self.pending!r}")
            try:
                chunk = os.read(self.fd, 4096)
            except OSError:  # the child closed the terminal
                chunk = b""
            if not chunk:
                raise AssertionError(f"the terminal closed before {needle!r}: {self.pending!r}")
            self.pending += chunk
            self.log += chunk
        end = self.pending.index(needle) + len(needle)
        seen, self.pending = self.pending[:end], self.pending[end:]
        return seen

    def rest(self, timeout_s: float = 10.0) -> bytes:
        """Everything until the child closes the terminal."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and select.select([self.fd], [], [], 0.1)[0]:
            try:
                chunk = os.read(self.fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            self.pending += chunk
            self.log += chunk
        rest, self.pending = self.pending, b""
        return rest


def test_a_pty_reader_keeps_what_follows_the_marker() -> None:
    primary, secondary = os.openpty()
    try:
        tty.setraw(secondary)
        os.write(secondary, b"camera_phi 10.02\xc2\xb0  (read back)\r\ngonio> ")  # one burst
        reader = PtyReader(primary)
        assert reader.until(b"(read back)").endswith(b"(read back)")
        assert reader.until(b"gonio> ", timeout_s=1.0) == b"\r\ngonio> "
    finally:
        os.close(primary)
        os.close(secondary)


def test_at_a_terminal_it_prompts_completes_and_keeps_history(tmp_path: Path) -> None:
    primary, secondary = os.openpty()
    state = tmp_path / "state"
    proc = subprocess.Popen(
        [*GONIO, "console", "--rig", str(RIG)], stdin=secondary, stdout=secondary,
        stderr=secondary, cwd=ROOT, close_fds=True,
        env={**os.environ, "XDG_STATE_HOME": str(state), "TERM": "dumb"},
    )
    os.close(secondary)
    reader = PtyReader(primary)
    try:
        reader.until(b"gonio> ")
        os.write(primary, b"jog camera_p\t 10\r")  # tab completes the axis name
        assert b"camera_phi 10.02" in reader.until(b"(read back)")
        reader.until(b"gonio> ")
        os.write(primary, b"quit\r")
        assert proc.wait(timeout=60) == 0
        reader.rest()
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(primary)
    history = (state / "gonio" / "console_history").read_text()
    assert "jog camera_phi 10" in history and "quit" in history
    assert SIM_COLLISION_LOG.encode() not in reader.log  # nor did this child's simulator


def test_history_tolerates_an_unwritable_home(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    import readline

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    assert history_path() == tmp_path / "state" / "gonio" / "console_history"
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with readline_history(blocker / "gonio" / "console_history"):  # cannot read nor write
        readline.add_history("status")
    assert blocker.read_text() == "not a folder"


# ---------------------------------------------------------------------- status, routes
def test_status_shows_the_pose_the_joints_realise(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["status", "--rig", str(RIG), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["pose"] == {"theta_i_deg": pytest.approx(0.0, abs=1e-6),
                               "theta_r_deg": pytest.approx(45.0, abs=1e-6),
                               "delta_phi_deg": None}
    with open_console(RIG) as con:
        con.move_pose(40.0, 20.0, 90.0)
        pose = con.pose()
    assert (pose.theta_i, pose.theta_r) == (pytest.approx(40.0, abs=0.1),
                                            pytest.approx(20.0, abs=0.1))
    assert abs(pose.delta_phi) == pytest.approx(90.0, abs=0.1)


def test_a_routed_jog_prints_its_route_first(capsys: pytest.CaptureFixture[str],
                                             sims: list[SimServoBus]) -> None:
    # From park the light arm swings through the camera's arc: it must go round the camera.
    assert main(["jog", "light_theta", "55", "--rig", str(RIG)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("route: ") and " legs via " in lines[0]
    legs = lines[0].split(" → ")
    assert int(lines[0].split()[1]) == len(legs) >= 2
    assert legs[-1] == "light_theta 55.0° camera_theta 45.0° camera_phi 0.0°"
    assert lines[1] == "light_theta 55.02°  (read back)"
    (bus,) = sims
    assert bus.sim_collisions() == []  # (the autouse fixture checks this too)

    assert main(["jog", "light_theta", "55", "--rig", str(RIG), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)  # one JSON object, no route line
    assert payload["joints_deg"]["light_theta"] == pytest.approx(55.0, abs=TICK_DEG)
    assert len(payload["route"]) >= 2
    assert payload["route"][-1] == {"light_theta": 55.0, "camera_theta": 45.0, "camera_phi": 0.0}
    assert any(leg["camera_phi"] != 0.0 or leg["camera_theta"] != 45.0
               for leg in payload["route"][:-1])  # the camera stepped aside


def test_the_shell_prints_routes_too(monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert shell(monkeypatch, "jog light_theta 55\nhome\nstatus\n") == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("route: ") and out[1] == "light_theta 55.02°  (read back)"
    assert out[2].startswith("route: ")  # and back round the camera to park
    rows = status_rows("\n".join(out))
    for axis, deg in PARK.items():
        assert float(rows[axis][2]) == pytest.approx(deg, abs=TICK_DEG)


# ---------------------------------------------------------------------- [home]
def test_home_goes_to_the_declared_pose(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    rig = rig_with(tmp_path, "[home]\ntheta_i_deg = 30\ntheta_r_deg = 30\ndelta_phi_deg = 180\n")
    assert main(["home", "--rig", str(rig), "--json"]) == 0
    joints = json.loads(capsys.readouterr().out)["joints_deg"]
    assert set(joints) == set(PARK)
    with open_console(rig) as con:
        pose = con.pose(joints)
        assert con.home_deg == pytest.approx(joints, abs=TICK_DEG)
    assert (pose.theta_i, pose.theta_r) == (pytest.approx(30.0, abs=0.1),
                                            pytest.approx(30.0, abs=0.1))
    assert abs(pose.delta_phi) == pytest.approx(180.0, abs=0.1)

    # In the shell: home from elsewhere, then one axis alone back to its home angle.
    assert shell(monkeypatch, "home\njog camera_phi 30\nhome camera_phi\nstatus --json\n",
                 rig=rig) == 0
    status = json_lines(capsys.readouterr().out)[-1]
    assert status["pose"]["theta_i_deg"] == pytest.approx(30.0, abs=0.1)
    assert status["pose"]["theta_r_deg"] == pytest.approx(30.0, abs=0.1)


def test_home_as_joints_and_home_by_default_is_park(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    rig = rig_with(tmp_path, "[home]\njoints = { light_theta = -20.0, camera_theta = 30.0, "
                             "camera_phi = 90.0 }\n")
    assert shell(monkeypatch, "home --json\nhome light_theta --json\n", rig=rig) == 0
    first, second = json_lines(capsys.readouterr().out)
    assert first["joints_deg"] == pytest.approx(
        {"light_theta": -20.0, "camera_theta": 30.0, "camera_phi": 90.0}, abs=TICK_DEG)
    assert second["joints_deg"] == pytest.approx({"light_theta": -20.0}, abs=TICK_DEG)

    # No [home]: home is the park pose (not every axis at 0°, where the arms would collide).
    assert shell(monkeypatch, "jog camera_phi 30\njog light_theta -20\nhome --json\n") == 0
    *_, home = json_lines(capsys.readouterr().out)
    assert home["joints_deg"] == pytest.approx(PARK, abs=TICK_DEG)


@pytest.mark.parametrize(
    ("home", "match"),
    [
        ("[home]\ntheta_i_deg = 30\n", r"\[home\] theta_r_deg: is missing"),
        ("[home]\n", r"\[home\]: is empty"),
        ("[home]\ntheta_i_deg = 30\ntheta_r_deg = 30\ndelta_phi = 180\n",
         r"\[home\] delta_phi: unknown key"),
        ("[home]\ntheta_i_deg = 'up'\ntheta_r_deg = 30\ndelta_phi_deg = 180\n",
         r"\[home\] theta_i_deg: must be a number"),
        ("[home]\ntheta_i_deg = 30\njoints = { light_theta = 0 }\n",
         r"\[home\] theta_i_deg: give the home pose either as .* or as joints, not both"),
        ("[home]\njoints = { light_theta = 0, camera_theta = 45 }\n",
         r"\[home.joints\] camera_phi: is missing: give every axis a home angle"),
        ("[home]\njoints = { light_theta = 0, camera_theta = 45, camera_phi = 0, tilt = 1 }\n",
         r"\[home.joints\] tilt: names no axis of this rig"),
        ("[home]\njoints = { light_theta = 0, camera_theta = 45, camera_phi = 200 }\n",
         r"\[home.joints\] camera_phi: must be ≤ 179°, got 200°"),
        ("[home]\ntheta_i_deg = 30\ntheta_r_deg = 88\ndelta_phi_deg = 180\n",
         r"\[home\]: pose θi=30° θr=88° Δφ=180° is outside the joint limits"),
        ("home = 3\n", r"home: must be a table, got 3"),
    ],
)
def test_a_malformed_home_is_one_line(tmp_path: Path, home: str, match: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    if home.startswith("home ="):  # a top-level key must come before the tables
        path = tmp_path / "rig-home.toml"
        path.write_text(home + RIG.read_text())
    else:
        path = rig_with(tmp_path, home)
    with pytest.raises(ConfigError, match=match) as info:
        load_rig(path)
    assert "\n" not in str(info.value)
    assert main(["status", "--rig", str(path)]) == 2
    assert str(path) in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize(
    ("home", "match"),
    [
        # light and camera in the same direction: the arms would meet
        ("[home]\ntheta_i_deg = 30\ntheta_r_deg = 30\ndelta_phi_deg = 0\n",
         r"\[home\] pose θi=30° θr=30° Δφ=0° is not safe \(arm-collision"),
        ("[home]\njoints = { light_theta = 0, camera_theta = 0, camera_phi = 0 }\n",
         r"\[home\] joints light_theta = 0, camera_theta = 0, camera_phi = 0 is not safe "
         r"\(arm-collision"),
    ],
)
def test_an_unsafe_home_is_refused_when_the_console_opens(
        tmp_path: Path, home: str, match: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    rig = rig_with(tmp_path, home)
    load_rig(rig)  # the file itself is well formed; the guard decides
    with pytest.raises(ConfigError, match=match), open_console(rig):
        pass
    assert shell(monkeypatch, "status\n", rig=rig) == 2
    assert "choose a safe home pose" in one_error_line(capsys.readouterr().err)


# ---------------------------------------------------------------------- the light stage
@pytest.mark.parametrize(
    ("argv", "verb"),
    [
        (["status"], "report the status of"),
        (["scan"], "scan"),
        (["jog", "light", "1"], "jog"),
        (["move", "--theta-i", "10", "--theta-r", "30", "--delta-phi", "180"], "move"),
        (["home"], "home"),
        (["park"], "park"),
        (["torque", "off"], "switch torque on or off for"),
        (["reboot", "light"], "reboot"),
        (["console"], "drive from a console"),
    ],
)
def test_the_light_stage_refuses_every_console_verb_in_one_line(
        argv: list[str], verb: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("status\n"))
    assert main([*argv, "--rig", str(LIGHT_STAGE)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert one_error_line(captured.err) == (
        f"gonio: error: {LIGHT_STAGE}: the light stage has no moving axes: nothing to {verb}; "
        "its lights are driven by gonio lightstage capture")


def test_a_home_table_on_the_light_stage_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "stage.toml"
    path.write_text(LIGHT_STAGE.read_text().replace(
        "[light_stage]", "[home]\ntheta_i_deg = 0\ntheta_r_deg = 30\ndelta_phi_deg = 0\n\n"
                         "[light_stage]"))
    with pytest.raises(ConfigError, match=r"\[home\]: the light stage has no moving axes"):
        load_rig(path)


def test_the_issues_move_through_the_camera_is_routed(
        capsys: pytest.CaptureFixture[str], sims: list[SimServoBus]) -> None:
    # `gonio move --theta-i 20 --theta-r 0 --delta-phi 0` from park swung the light through
    # the camera: now the camera steps aside first and the move reads back its target.
    assert main(["move", "--theta-i", "20", "--theta-r", "0", "--delta-phi", "0", "--rig",
                 str(RIG), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert len(payload["route"]) >= 2  # not the direct move
    assert payload["joints_deg"]["light_theta"] == pytest.approx(20.0, abs=TICK_DEG)
    assert payload["joints_deg"]["camera_theta"] == pytest.approx(0.0, abs=TICK_DEG)
    assert all(bus.sim_collisions() == [] for bus in sims)
