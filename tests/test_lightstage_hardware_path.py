"""The light stage's real-hardware path without hardware: a SimDmxWidget started on its own and
named in the rig file by a plain device path (through a symlink, like /dev/serial/by-id), the
real DmxWidget/LightController on the host clock, and the real GPhoto2Camera driver over a
stand-in ``gphoto2`` module whose camera writes real DNGs (as tests/test_calib_gphoto2_driver.py
does for the driver itself)."""

from __future__ import annotations

import dataclasses
import os
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest
from gphoto2_standin import Choice, Config, stand_in_module

from acquisition.config.rig import load_rig
from acquisition.config.stage import stage_config
from acquisition.lightstage.capture import capture_lightstage, resume_lightstage
from acquisition.lightstage.devices import exposure_interval, open_lightstage
from acquisition.lightstage.reduce import led_calibration
from acquisition.session.engine import StepEvent
from acquisition.session.folder import SessionFolder
from acquisition.session.observers import Observer
from drivers.camera import CaptureInfo
from drivers.errors import CommunicationError, ConfigError, HardwareError
from drivers.gphoto2 import parse_shutter
from drivers.storage import is_partial
from simulators.dmx import SimDmxWidget
from simulators.dng import write_dng

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "rig-lightstage.toml"
N_LEDS = 16
BLACK_DN = 512
DN_PER_LED = 2000  # the stand-in camera's signal per fully lit LED


class Plugged:
    """The widget currently on the rig's port (a symlink re-pointed at each replug)."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.sim: SimDmxWidget | None = None

    def plug(self) -> SimDmxWidget:
        sim = SimDmxWidget()  # host clock, like a real widget
        tmp = self.link.with_suffix(".new")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(sim.start())
        os.replace(tmp, self.link)
        self.sim = sim
        return sim

    def unplug(self) -> None:
        assert self.sim is not None
        self.sim.sim_unplug()


def stand_in_gphoto2(plugged: Plugged) -> types.ModuleType:
    """A ``gphoto2`` module whose camera exposes for the set shutter speed and writes a DNG whose
    signal is the number of LEDs the widget was outputting (recorded in ``gp.shots``)."""
    shots: list[tuple[float, float, list[bytes]]] = []

    def settings() -> Config:
        return Config({"shutterspeed": Choice(["1/250", "1/100", "1/50"], "1/250"),
                       "iso": Choice(["100", "200"], "200")})

    class Camera:
        def __init__(self) -> None:
            self.config = settings()

        def init(self) -> None:
            pass

        def get_config(self) -> Config:
            return self.config

        def set_config(self, config: Config) -> None:
            self.config = config

        def capture(self, kind: int) -> types.SimpleNamespace:
            exposure = parse_shutter(self.config.widgets["shutterspeed"].value)
            assert plugged.sim is not None and exposure is not None
            t0 = time.monotonic()
            time.sleep(exposure)
            t1 = time.monotonic()
            shown = plugged.sim.sim_states_during(t0, t1)
            shots.append((t0, t1, shown))
            lit = sum(shown[-1]) / 255.0
            name = f"IMG_{len(shots):04d}.DNG"
            self.pending = (name, lit, exposure)
            return types.SimpleNamespace(folder="/DCIM/100CANON", name=name)

        def file_get(self, folder: str, name: str, kind: int) -> types.SimpleNamespace:
            _, lit, exposure = self.pending
            mosaic = np.full((64, 64), BLACK_DN + DN_PER_LED * lit, dtype=np.uint16)
            return types.SimpleNamespace(save=lambda p: write_dng(
                p, mosaic, black_level=BLACK_DN, white_level=65535, exposure_s=exposure,
                iso=100))

        def exit(self) -> None:
            gp.closed += 1

    gp = stand_in_module(Camera)
    gp.shots = shots
    gp.closed = 0
    return gp


@pytest.fixture
def rig_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, Plugged, object]:
    """The example rig with its widget port on a symlink to a separately started SimDmxWidget,
    the ROI on the stand-in's 32×32-superpixel frames, and the stand-in ``gphoto2``."""
    plugged = Plugged(tmp_path / "ttyUSB-dmx")
    plugged.plug()
    text = EXAMPLE.read_text()
    for old, new in (('"/dev/ttyUSB0" }', f'"{plugged.link}" }}'),
                     ("roi = [1400, 900, 1600, 1100]", "roi = [8, 8, 24, 24]")):
        assert old in text
        text = text.replace(old, new)
    rig = tmp_path / "rig-lightstage.toml"
    rig.write_text(text)
    gp = stand_in_gphoto2(plugged)
    monkeypatch.setitem(sys.modules, "gphoto2", gp)
    yield rig, plugged, gp
    if plugged.sim is not None:
        plugged.sim.stop()


class _UnplugAfter(Observer):
    def __init__(self, plugged: Plugged, after: int) -> None:
        self.plugged, self.after = plugged, after

    def step(self, event: StepEvent) -> None:
        if event.done == self.after:
            self.plugged.unplug()


def test_real_path_captures_confirmed_frames_and_resumes_after_an_unplug(rig_file) -> None:
    rig, plugged, gp = rig_file
    first = plugged.sim
    asked: list[str] = []
    out = rig.parent / "session"
    with pytest.raises(CommunicationError, match="stopped responding") as err:
        capture_lightstage(rig, out, prompt=asked.append, observers=[_UnplugAfter(plugged, 20)])
    assert "\n" not in str(err.value) and "USB cable" in str(err.value)
    # the driver really talked to the separately started widget: probed it, sent universes
    assert first.sim_received()[3] >= 1 and first.sim_received()[6] >= 20
    assert not any(first.sim_errors().values())
    assert asked == ["white", "sample"]  # white OLAT (16 frames), dark, then the sample
    assert gp.closed == 1  # camera released on the way out
    folder = SessionFolder(out)
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
    assert sum(r.status == "done" for r in records) == 20
    assert not any(r.status == "done" for r in records[20:])
    assert not [p for p in folder.frames_dir.iterdir() if is_partial(p)]
    kept = {r.frame: (folder.frames_dir / str(r.frame)).read_bytes()
            for r in records if r.status == "done"}

    second = plugged.plug()  # plugged back in: same port name, a new widget
    result = resume_lightstage(out, prompt=asked.append)
    assert asked[2:] == ["sample"]
    assert result.counts == {"done": 2 * N_LEDS + 1}
    assert second.sim_received()[6] >= 2 * N_LEDS + 1 - 20
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
    assert all((folder.frames_dir / name).read_bytes() == data for name, data in kept.items())
    # the widget's own output model agrees with the driver's timing: each frame's exposure
    # saw one light state, the commanded one (OLAT: exactly LED k; dark: nothing)
    shots = gp.shots
    assert len(shots) == 2 * N_LEDS + 1
    expected = list(range(N_LEDS)) + [None] + list(range(N_LEDS))
    for (_, _, shown), k in zip(shots, expected, strict=True):
        assert len(shown) == 1
        lit = [i for i, v in enumerate(shown[0]) if v]
        assert lit == ([] if k is None else [k]) and (k is None or shown[0][k] == 255)
    # the frames are real DNGs the reduction reads: every LED calibrates from its white frame
    cal = led_calibration(out)
    assert (cal.pixels > 0).all()
    assert np.isfinite(cal.scale).all() and (cal.scale > 0).all()


def test_a_frame_exposed_before_the_light_settled_is_refused(rig_file, tmp_path: Path) -> None:
    rig_path, _, gp = rig_file
    rig = load_rig(rig_path)
    stage = dataclasses.replace(stage_config(rig), settle_s=0.5)  # a wide unsettled window
    with open_lightstage(rig, material=None, stage=stage, prompt=lambda target: None) as dev:
        assert dev.sims == {} and dev.clock is None  # the hardware path, on the host clock
        dev.lights.olat(3, wait=False)
        with pytest.raises(HardwareError, match="not surely on"):
            dev.capture(tmp_path / "early.dng", 0.01, 100, 0)
        dev.lights.wait_ready()
        dev.capture(tmp_path / "settled.dng", 0.01, 100, 1)
        assert dev.lights.state is not None and dev.lights.state.lit == ("L003",)
    assert len(gp.shots) == 2


def test_a_camera_reporting_an_exposure_outside_the_call_widens_the_interval() -> None:
    info = CaptureInfo(Path("f.dng"), exposure_s=0.01, iso=100, timestamp=1000.0)
    # reported start (host 99.5) before the call (100.0): a stale frame; the interval widens
    assert exposure_interval(info, 100.0, 100.2, wall_minus_host_s=900.5) == (99.5, 100.2)
    # reported inside the bracket: the bracket stands
    start, end = exposure_interval(info, 99.9, 100.2, wall_minus_host_s=900.0)
    assert (start, end) == (99.9, 100.2)


def test_without_an_operator_the_capture_is_refused_before_anything_is_created(
        rig_file) -> None:
    rig, _, _ = rig_file
    out = rig.parent / "s"
    with pytest.raises(ConfigError, match="no one to ask .*: run it in a terminal or "
                                          "pass prompt=") as err:
        capture_lightstage(rig, out)
    assert "\n" not in str(err.value) and not out.exists()


def test_simulated_widget_port_with_a_real_camera_is_refused(rig_file) -> None:
    rig_path, _, _ = rig_file
    text = rig_path.read_text()
    rig_path.write_text(text.replace(f'ports = {{ 1 = "{rig_file[1].link}" }}',
                                     'ports = { 1 = "sim" }'))
    with pytest.raises(ConfigError, match=r'universe 1 is "sim" but the camera is real'), \
            open_lightstage(load_rig(rig_path), material=None, prompt=print):
        pass
