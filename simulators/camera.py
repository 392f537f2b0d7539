"""A simulated camera: renders the scene, exposes a :class:`SensorModel`, writes a real DNG.

The scene is a callable returning the radiance (W·sr⁻¹·m⁻², per superpixel, (H/2)×(W/2)×3)
the camera sees *now*; acquisition builds it from the simulator's true rig geometry. While a
frame is rendered and written, the shared :class:`SimClock` is frozen, then it is advanced by
the exposure time, so a capture costs exactly its exposure in simulated time.

Noise is reproducible: frame ``n`` of a camera with seed ``s`` uses the noise seed derived
from ``(s, n)``; pass ``frame_seed`` (e.g. the pose index) to make a frame independent of how
many frames came before it (resuming a session re-shoots identical frames).
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from drivers.camera import CameraError, CaptureInfo
from drivers.errors import StorageError
from simulators.clock import SimClock
from simulators.dng import write_dng
from simulators.sensor import CFA_PATTERN, SensorModel

SIM_EPOCH = _dt.datetime(2000, 1, 1)
"""Wall-clock date written as ``DateTime`` for simulated time 0."""

MAX_EXPOSURE_S = 3600.0
"""Longest exposure the simulated camera accepts, s."""


class SimCamera:
    """Simulated RAW camera (implements :class:`drivers.camera.Camera`).

    Parameters
    ----------
    sensor:
        The sensor model (size, noise, gain, lens f-number).
    scene:
        ``scene() -> radiance_rgb``: radiance seen at the moment of the call.
    clock:
        Shared simulated clock; None uses host time and does not advance anything.
    seed:
        Camera seed (≥ 0) from which per-frame noise seeds are derived.
    make, model:
        Written into each DNG.
    """

    def __init__(
        self,
        sensor: SensorModel,
        scene: Callable[[], np.ndarray],
        clock: SimClock | None = None,
        seed: int = 0,
        *,
        make: str = "gonio",
        model: str = "SimCam",
    ) -> None:
        if not isinstance(seed, int) or seed < 0:
            raise ValueError(f"camera seed must be a whole number ≥ 0, got {seed!r}")
        self.sensor = sensor
        self._scene = scene
        self._clock = clock
        self._seed = seed
        self._make = make
        self._model = model
        self._frames = 0
        self._lock = threading.Lock()

    @property
    def frames_taken(self) -> int:
        """Number of successful captures so far."""
        return self._frames

    def describe(self) -> dict[str, Any]:
        """Make, model, sensor size, bit depth, CFA pattern, f-number and sensor parameters."""
        s = self.sensor
        return {
            "source": "simulator",
            "make": self._make,
            "model": self._model,
            "width_px": s.width,
            "height_px": s.height,
            "bits": s.bits,
            "cfa_pattern": CFA_PATTERN,
            "black_level_dn": s.black_level_dn,
            "f_number": s.f_number,
            "seed": self._seed,
            "sensor": s.to_dict(),
        }

    def frame_seed_for(self, index: int) -> int:
        """Noise seed of frame ``index`` for this camera's seed (a 63-bit integer)."""
        state = np.random.SeedSequence([self._seed, int(index)]).generate_state(2, np.uint32)
        return (int(state[0]) << 31) ^ int(state[1])

    def capture(
        self,
        path: str | os.PathLike[str],
        exposure_s: float,
        iso: float = 100.0,
        *,
        frame_seed: int | None = None,
    ) -> CaptureInfo:
        """Render the scene, expose, write the DNG to ``path`` (fsynced), advance the clock.

        Parameters
        ----------
        path:
            Output DNG path (overwritten).
        exposure_s:
            Exposure time, s (0 < t ≤ :data:`MAX_EXPOSURE_S`).
        iso:
            ISO speed (50 … 102400).
        frame_seed:
            Index from which this frame's noise seed is derived; None uses the running frame
            counter.
        """
        if not (math.isfinite(exposure_s) and 0 < exposure_s <= MAX_EXPOSURE_S):
            raise CameraError(
                f"{self._model}: exposure {exposure_s} s is outside 0…{MAX_EXPOSURE_S:g} s; "
                "choose a positive exposure time"
            )
        if not (math.isfinite(iso) and 50 <= iso <= 102400):
            raise CameraError(f"{self._model}: ISO {iso} is outside 50…102400; choose another ISO")
        path = Path(path)
        with self._lock, self._frozen():
            start = self._clock.now() if self._clock is not None else time.time()
            index = self._frames if frame_seed is None else frame_seed
            radiance = self._scene()
            mosaic = self.sensor.expose(radiance, exposure_s, iso, self.frame_seed_for(index))
            if self._clock is not None:
                taken = SIM_EPOCH + _dt.timedelta(seconds=start)
            else:
                taken = _dt.datetime.fromtimestamp(start)
            try:
                write_dng(
                    path,
                    mosaic,
                    cfa_pattern=CFA_PATTERN,
                    black_level=self.sensor.black_level_dn,
                    white_level=self.sensor.white_level_dn(iso),
                    exposure_s=exposure_s,
                    iso=iso,
                    f_number=self.sensor.f_number,
                    make=self._make,
                    model=self._model,
                    datetime=taken,
                    active_area=self.sensor.active_area if self.sensor.optical_black_px else None,
                    masked_areas=self.sensor.masked_areas,
                    fsync=True,
                )
            except OSError as exc:
                raise StorageError(
                    f"{self._model}: cannot write frame {path} ({exc.strerror or exc}); "
                    "check the folder exists, is writable and the disk is not full"
                ) from exc
            if self._clock is not None:
                self._clock.advance(exposure_s)
            self._frames += 1
        return CaptureInfo(path=path, exposure_s=float(exposure_s), iso=float(iso), timestamp=start)

    def _frozen(self) -> AbstractContextManager[None]:
        return nullcontext() if self._clock is None else self._clock.frozen()
