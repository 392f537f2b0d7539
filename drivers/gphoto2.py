"""DSLR / mirrorless cameras over libgphoto2 (the optional ``gphoto2`` extra).

:class:`GPhoto2Camera` implements :class:`drivers.camera.Camera`. The ``gphoto2`` package is
imported only when a camera is opened, so gonio runs without it; a missing package or camera
gives one :class:`~drivers.camera.CameraError` line saying what to do.

Cameras accept a fixed list of shutter speeds and ISOs: a capture uses the nearest choice and
:class:`~drivers.camera.CaptureInfo` reports the exposure and ISO actually set. Every libgphoto2
call runs with a timeout (a hung USB transfer becomes a ``CameraError``; the stuck call itself
cannot be cancelled, so the camera is marked unusable until reopened).
"""

from __future__ import annotations

import importlib
import math
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from drivers.camera import CameraError, CaptureInfo
from drivers.errors import StorageError

T = TypeVar("T")

INSTALL_HINT = "install it with: pip install 'gonio[gphoto2]' (needs libgphoto2)"


def parse_shutter(text: str) -> float | None:
    """Seconds for a gphoto2 shutter-speed choice ("1/250", "0.3", "2", '30"', "15s"); None for
    "bulb", "auto" and other non-times."""
    t = text.strip().rstrip('s"').strip()
    try:
        if "/" in t:
            num, den = t.split("/", 1)
            value = float(num) / float(den)
        else:
            value = float(t)
    except (ValueError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def nearest_choice(
    choices: list[str], target: float, parse: Callable[[str], float | None]
) -> tuple[str, float]:
    """The choice whose value is nearest ``target`` in log scale, and that value."""
    parsed = [(c, v) for c in choices if (v := parse(c)) is not None]
    if not parsed:
        raise CameraError(f"camera offers no usable value among {choices!r}")
    return min(parsed, key=lambda cv: abs(math.log(cv[1] / target)))


def _parse_iso(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if value > 0 else None


class GPhoto2Camera:
    """A camera on USB through libgphoto2.

    Parameters
    ----------
    port:
        gphoto2 port string (e.g. ``"usb:001,007"``); None takes the first camera found.
    timeout_s:
        Longest wait for one libgphoto2 call beyond the exposure itself, s.
    """

    def __init__(self, port: str | None = None, *, timeout_s: float = 30.0) -> None:
        try:
            self._gp = importlib.import_module("gphoto2")
        except ImportError:
            raise CameraError(f"python-gphoto2 is not installed; {INSTALL_HINT}") from None
        self.port = port
        self.timeout_s = timeout_s
        self._broken = False
        self._lock = threading.Lock()
        self._camera = self._call(self._open, "open the camera")

    # -- plumbing ----------------------------------------------------------------------------
    def _call(self, fn: Callable[[], T], what: str, extra_s: float = 0.0) -> T:
        """Run ``fn`` in a worker thread; CameraError on a gphoto2 error or a timeout."""
        if self._broken:
            raise CameraError(f"camera {self._where()}: an earlier call hung; unplug/replug the "
                              "camera and reopen it")
        box: dict[str, Any] = {}

        def run() -> None:
            try:
                box["value"] = fn()
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
                box["error"] = exc

        worker = threading.Thread(target=run, name="gphoto2-call", daemon=True)
        worker.start()
        worker.join(self.timeout_s + extra_s)
        if worker.is_alive():
            self._broken = True
            raise CameraError(
                f"camera {self._where()}: no answer within {self.timeout_s + extra_s:g} s while "
                f"trying to {what}; check the USB cable and that the camera is awake"
            )
        if "error" in box:
            raise self._translate(box["error"], what) from box["error"]
        return box["value"]

    def _where(self) -> str:
        return self.port or "(first found)"

    def _translate(self, exc: BaseException, what: str) -> BaseException:
        gp = self._gp
        if isinstance(exc, gp.GPhoto2Error):
            if exc.code == getattr(gp, "GP_ERROR_MODEL_NOT_FOUND", -105):
                return CameraError("no camera found by gphoto2; connect and switch on the camera, "
                                   "and close other programs using it (gvfs, Shotwell)")
            if exc.code == getattr(gp, "GP_ERROR_IO_USB_CLAIM", -53):
                return CameraError(f"camera {self._where()} is claimed by another program; close "
                                   "it (e.g. gvfs-gphoto2-volume-monitor) and retry")
            return CameraError(f"camera {self._where()}: cannot {what} (gphoto2 error "
                               f"{exc.code}: {exc}); check the camera's mode and memory card")
        return exc

    def _open(self) -> Any:
        gp = self._gp
        camera = gp.Camera()
        if self.port is not None:
            ports = gp.PortInfoList()
            ports.load()
            camera.set_port_info(ports[ports.lookup_path(self.port)])
        camera.init()
        return camera

    # -- Camera protocol ---------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        """Make, model, serial and port as the camera reports them."""
        def summary() -> dict[str, Any]:
            config = self._camera.get_config()
            out: dict[str, Any] = {"source": "gphoto2", "port": self.port}
            for key in ("manufacturer", "cameramodel", "serialnumber"):
                try:
                    out[key] = config.get_child_by_name(key).get_value()
                except self._gp.GPhoto2Error:
                    out[key] = None
            return out

        with self._lock:
            return self._call(summary, "read its configuration")

    def _set_choice(self, config: Any, name: str, target: float,
                    parse: Callable[[str], float | None]) -> float:
        try:
            widget = config.get_child_by_name(name)
        except self._gp.GPhoto2Error:
            raise CameraError(f"camera {self._where()} has no '{name}' setting; put it in "
                              "manual (M) mode") from None
        choices = [widget.get_choice(i) for i in range(widget.count_choices())]
        choice, value = nearest_choice(choices, target, parse)
        widget.set_value(choice)
        return value

    def capture(self, path: str | os.PathLike[str], exposure_s: float, iso: float) -> CaptureInfo:
        """Set the nearest shutter speed and ISO, shoot, download the RAW to ``path``."""
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise CameraError(f"exposure {exposure_s} s must be a positive time")
        path = Path(path)

        def configure() -> tuple[float, float]:
            config = self._camera.get_config()
            t = self._set_choice(config, "shutterspeed", exposure_s, parse_shutter)
            s = self._set_choice(config, "iso", iso, _parse_iso)
            self._camera.set_config(config)
            return t, s

        def shoot() -> Any:
            return self._camera.capture(self._gp.GP_CAPTURE_IMAGE)

        with self._lock:
            used_t, used_iso = self._call(configure, "set shutter speed and ISO")
            start = time.time()
            where = self._call(shoot, "take a picture", extra_s=used_t)

            def download() -> None:
                cam_file = self._camera.file_get(where.folder, where.name,
                                                 self._gp.GP_FILE_TYPE_NORMAL)
                cam_file.save(str(path))
                with open(path, "rb+") as fh:
                    os.fsync(fh.fileno())

            try:
                self._call(download, f"download {where.folder}/{where.name}")
            except OSError as exc:
                raise StorageError(f"cannot write frame {path} ({exc.strerror or exc}); check the "
                                   "folder exists and the disk is not full") from exc
        return CaptureInfo(path=path, exposure_s=used_t, iso=used_iso, timestamp=start)

    def close(self) -> None:
        """Release the camera (safe to call twice)."""
        camera, self._camera = getattr(self, "_camera", None), None
        if camera is not None and not self._broken:
            self._call(camera.exit, "release the camera")

    def __enter__(self) -> GPhoto2Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
