"""drivers.gphoto2 without a camera: the missing package, a missing camera, choice selection,
download and timeouts, through a stand-in ``gphoto2`` module with libgphoto2's Python API."""

from __future__ import annotations

import sys
import threading
import types
from pathlib import Path

import pytest
from gphoto2_standin import Choice, Config, StandInError, stand_in_module

from drivers.camera import Camera, CameraError
from drivers.gphoto2 import GPhoto2Camera, nearest_choice, parse_shutter

FakeError = StandInError
Widget = Choice


def fake_module(*, present: bool = True, hang: threading.Event | None = None) -> types.ModuleType:
    state: dict[str, object] = {}

    class FakeCamera:
        def __init__(self) -> None:
            self.config = Config({
                "shutterspeed": Widget(["bulb", "30", "1/2", "1/100", "1/125", "1/250"], "1/125"),
                "iso": Widget(["Auto", "100", "200", "400"], "Auto"),
                "cameramodel": Widget([], "Fake D850"),
            })
            state["camera"] = self

        def init(self) -> None:
            if not present:
                raise FakeError(-105)

        def get_config(self) -> Config:
            return self.config

        def set_config(self, config: Config) -> None:
            state["set"] = {k: w.value for k, w in config.widgets.items()}

        def capture(self, kind: int) -> types.SimpleNamespace:
            if hang is not None:
                hang.wait(5)
            return types.SimpleNamespace(folder="/store_00010001/DCIM/100D850", name="DSC_0001.NEF")

        def file_get(self, folder: str, name: str, kind: int) -> object:
            return types.SimpleNamespace(save=lambda p: Path(p).write_bytes(b"NEF" + name.encode()))

        def exit(self) -> None:
            state["closed"] = True

    gp = stand_in_module(FakeCamera)
    gp.state = state
    return gp


def test_missing_package_is_one_clear_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gphoto2", None)  # import gphoto2 → ImportError
    hint = r"not installed; install it with: pip install 'gonio\[gphoto2\]'"
    with pytest.raises(CameraError, match=hint) as info:
        GPhoto2Camera()
    assert "\n" not in str(info.value)


def test_no_camera_connected(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gphoto2", fake_module(present=False))
    with pytest.raises(CameraError, match="no camera found by gphoto2; connect and switch on"):
        GPhoto2Camera()


def test_capture_uses_nearest_choices_and_downloads(monkeypatch, tmp_path: Path) -> None:
    gp = fake_module()
    monkeypatch.setitem(sys.modules, "gphoto2", gp)
    with GPhoto2Camera(timeout_s=2.0) as cam:
        assert isinstance(cam, Camera)
        assert cam.describe()["cameramodel"] == "Fake D850"
        info = cam.capture(tmp_path / "f.nef", 0.009, 150)
    assert gp.state["set"]["shutterspeed"] == "1/100" and gp.state["set"]["iso"] in ("100", "200")
    assert info.exposure_s == pytest.approx(0.01)
    assert (tmp_path / "f.nef").read_bytes() == b"NEFDSC_0001.NEF"
    assert gp.state["closed"] is True


def test_hung_capture_times_out_and_marks_the_camera_unusable(monkeypatch, tmp_path: Path) -> None:
    release = threading.Event()
    monkeypatch.setitem(sys.modules, "gphoto2", fake_module(hang=release))
    cam = GPhoto2Camera(timeout_s=0.05)
    with pytest.raises(CameraError, match="no answer within"):
        cam.capture(tmp_path / "f.nef", 0.004, 100)
    with pytest.raises(CameraError, match="reopen"):
        cam.capture(tmp_path / "g.nef", 0.004, 100)
    release.set()


def test_shutter_parsing_and_nearest_choice() -> None:
    assert parse_shutter("1/250") == pytest.approx(0.004)
    assert parse_shutter('30"') == 30 and parse_shutter("15s") == 15 and parse_shutter("0.3") == 0.3
    assert parse_shutter("bulb") is None and parse_shutter("1/0") is None
    assert nearest_choice(["1/2", "1", "2"], 0.8, parse_shutter) == ("1", 1.0)
    with pytest.raises(CameraError, match="no usable value"):
        nearest_choice(["bulb"], 1.0, parse_shutter)
