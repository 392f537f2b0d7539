"""A physical model of a Bayer (RGGB) image sensor: radiance in, uint16 raw mosaic out.

Per pixel, the expected charge is ::

    μ_e = L_c · k · q_c · PRNU · V · t + I_dark · t

with ``L_c`` the radiance (W·sr⁻¹·m⁻²) of the pixel's colour ``c``, ``k`` =
``electrons_per_radiance_s`` (electrons per second per unit radiance, for the lens at its
``f_number``), ``q_c`` the relative quantum sensitivity, ``PRNU`` a fixed per-pixel gain
pattern (from the sensor seed), ``V`` the cos⁴ vignetting and ``I_dark`` the dark current.
The collected charge is Poisson(μ_e), clipped at the full well; read noise (e⁻) is added, the
result is divided by the conversion gain (e⁻/DN, inversely proportional to ISO), offset by
the black level, disturbed by black-level noise (DN, after the gain), rounded and clipped to
the ADC range 0 … 2^bits − 1.

``radiance_rgb`` is given **per superpixel**: an (H/2)×(W/2)×3 array (or anything that
broadcasts to it, e.g. a constant RGB triple), one radiance per 2×2 RGGB cell, so the
simulation grid is exactly the grid of :func:`calibration.linearize.linearize`'s output.

A frame depends only on (sensor seed, frame seed, radiance, exposure, ISO).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from drivers.errors import ConfigError
from simulators.exposure import expose_mosaic, frame_key

CFA_PATTERN = "RGGB"
"""Colour layout of every simulated sensor (top-left 2×2, row by row)."""

_PRNU_STREAM = 0x5052  # spawn key of the fixed-pattern random stream


@dataclass(frozen=True)
class SensorModel:
    """Sensor parameters; every field can be set from a rig file table (see :meth:`from_dict`).

    Attributes
    ----------
    width, height:
        Mosaic size in pixels (both even).
    bits:
        ADC depth; raw values lie in 0 … 2^bits − 1 DN.
    black_level_dn:
        Offset added to every pixel, DN (whole number).
    black_noise_dn:
        Gaussian noise after the gain stage (ADC / black-level noise), DN rms.
    read_noise_e:
        Gaussian read noise before the gain stage, e⁻ rms.
    full_well_e:
        Charge capacity of a pixel, e⁻.
    gain_e_per_dn:
        Conversion gain at ISO 100, e⁻/DN; at ISO ``s`` it is ``gain_e_per_dn · 100 / s``.
    dark_current_e_per_s:
        Mean dark current, e⁻/s per pixel (Poisson, like the signal).
    prnu_sigma:
        Relative rms of the fixed per-pixel response non-uniformity (0.01 = 1 %).
    vignetting_focal_px:
        Focal length in pixels for cos⁴ vignetting about the sensor centre; None = off.
    quantum_sensitivity:
        Relative sensitivity of the (R, G, B) pixels.
    electrons_per_radiance_s:
        e⁻ per second per W·sr⁻¹·m⁻² of radiance, for a pixel of sensitivity 1 at the lens's
        ``f_number`` (the lens has a fixed aperture).
    f_number:
        Aperture of the lens, written into each frame's metadata.
    seed:
        Seed of the fixed pattern (PRNU) and part of every frame's noise seed.
    optical_black_px:
        Width of a masked (optical-black) border on the top and left of the active area, px
        (even; 0 = none). Masked pixels collect dark current but no light.
    """

    width: int = 800
    height: int = 600
    bits: int = 14
    black_level_dn: int = 512
    black_noise_dn: float = 1.0
    read_noise_e: float = 3.0
    full_well_e: float = 30000.0
    gain_e_per_dn: float = 2.0
    dark_current_e_per_s: float = 0.5
    prnu_sigma: float = 0.005
    vignetting_focal_px: float | None = None
    quantum_sensitivity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    electrons_per_radiance_s: float = 1.0e4
    f_number: float = 8.0
    seed: int = 0
    optical_black_px: int = 0

    def __post_init__(self) -> None:
        def bad(name: str, rule: str) -> ConfigError:
            value = getattr(self, name)
            return ConfigError(f"sensor parameter '{name}' = {value!r} must be {rule}")

        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 2 or value % 2:
                raise bad(name, "an even whole number ≥ 2 (pixels)")
        if not isinstance(self.bits, int) or not 8 <= self.bits <= 16:
            raise bad("bits", "a whole number of bits in 8…16")
        if not isinstance(self.black_level_dn, int) or not 0 <= self.black_level_dn < self.adc_max:
            raise bad("black_level_dn", f"a whole number of DN in 0…{self.adc_max - 1}")
        for name in ("black_noise_dn", "read_noise_e", "dark_current_e_per_s", "prnu_sigma"):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                raise bad(name, "a finite number ≥ 0")
        for name in ("full_well_e", "gain_e_per_dn", "electrons_per_radiance_s", "f_number"):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) <= 0:
                raise bad(name, "a finite number > 0")
        if self.vignetting_focal_px is not None and not self.vignetting_focal_px > 0:
            raise bad("vignetting_focal_px", "> 0 pixels, or absent to turn vignetting off")
        qe = tuple(float(q) for q in self.quantum_sensitivity)
        if len(qe) != 3 or not all(math.isfinite(q) and q >= 0 for q in qe):
            raise bad("quantum_sensitivity", "three numbers ≥ 0 (R, G, B)")
        object.__setattr__(self, "quantum_sensitivity", qe)
        if not isinstance(self.seed, int) or self.seed < 0:
            raise bad("seed", "a whole number ≥ 0")
        ob = self.optical_black_px
        if not isinstance(ob, int) or ob < 0 or ob % 2:
            raise bad("optical_black_px", "an even whole number ≥ 0 (pixels)")

    @classmethod
    def from_dict(cls, params: Mapping[str, Any], *, where: str = "rig file") -> SensorModel:
        """Build a sensor from a rig-file table; unknown keys raise :class:`ConfigError`.

        ``where`` names the table in error messages (e.g. ``"rig-sim.toml [camera.sensor]"``).
        """
        known = [f.name for f in dataclasses.fields(cls) if f.init]
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise ConfigError(
                f"{where}: unknown sensor parameter(s) {', '.join(unknown)}; "
                f"known: {', '.join(known)}"
            )
        kwargs = dict(params)
        for name in ("width", "height", "bits", "black_level_dn", "seed", "optical_black_px"):
            if name in kwargs and isinstance(kwargs[name], float) and kwargs[name].is_integer():
                kwargs[name] = int(kwargs[name])
        try:
            return cls(**kwargs)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: invalid sensor parameter ({exc})") from None

    def to_dict(self) -> dict[str, Any]:
        """The parameters as a plain dict (inverse of :meth:`from_dict`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}

    @property
    def adc_max(self) -> int:
        """Largest raw value the ADC produces, DN."""
        return (1 << self.bits) - 1

    @property
    def raw_shape(self) -> tuple[int, int]:
        """Shape of the mosaic :meth:`expose` returns: the active area plus the masked border."""
        return self.height + self.optical_black_px, self.width + self.optical_black_px

    @property
    def active_area(self) -> tuple[int, int, int, int]:
        """(top, left, bottom, right) of the light-sensitive area in the raw mosaic."""
        ob = self.optical_black_px
        return ob, ob, ob + self.height, ob + self.width

    @property
    def masked_areas(self) -> list[tuple[int, int, int, int]]:
        """(top, left, bottom, right) rectangles of optical-black pixels (empty without border)."""
        ob = self.optical_black_px
        if ob == 0:
            return []
        rows, cols = self.raw_shape
        return [(0, 0, ob, cols), (ob, 0, rows, ob)]

    @property
    def superpixel_shape(self) -> tuple[int, int]:
        """Shape (H/2, W/2) expected of ``radiance_rgb``."""
        return self.height // 2, self.width // 2

    def gain_at(self, iso: float) -> float:
        """Conversion gain at ``iso``, e⁻/DN."""
        return self.gain_e_per_dn * 100.0 / iso

    def white_level_dn(self, iso: float) -> int:
        """Level where a pixel clips at ``iso``: full well or the ADC ceiling, whichever is lower."""
        return int(min(self.adc_max, self.black_level_dn + self.full_well_e / self.gain_at(iso)))

    @cached_property
    def response(self) -> np.ndarray:
        """Fixed electrons per (radiance · s) of each pixel (H×W float32): k · q_c · PRNU · V."""
        rng = np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(self.seed, spawn_key=(_PRNU_STREAM,)))
        )
        resp = 1.0 + self.prnu_sigma * rng.standard_normal((self.height, self.width))
        np.maximum(resp, 0.0, out=resp)
        if self.vignetting_focal_px is not None:
            y = np.arange(self.height) - (self.height - 1) / 2
            x = np.arange(self.width) - (self.width - 1) / 2
            r2 = (y[:, None] ** 2 + x[None, :] ** 2) / self.vignetting_focal_px**2
            resp /= (1.0 + r2) ** 2  # cos⁴θ with tanθ = r / f
        qr, qg, qb = self.quantum_sensitivity
        resp[0::2, 0::2] *= qr
        resp[0::2, 1::2] *= qg
        resp[1::2, 0::2] *= qg
        resp[1::2, 1::2] *= qb
        resp *= self.electrons_per_radiance_s
        resp = resp.astype(np.float32)
        resp.setflags(write=False)
        return resp

    def _checked_radiance(self, radiance_rgb: np.ndarray) -> np.ndarray:
        """Per-superpixel radiance as an (H/2, W/2, 3) float64 array (a view where possible);
        refuses another grid, negative or non-finite values."""
        h, w = self.superpixel_shape
        rad = np.asarray(radiance_rgb, dtype=np.float64)
        try:
            rad = np.broadcast_to(rad, (h, w, 3))
        except ValueError:
            raise ValueError(
                f"radiance_rgb of shape {rad.shape} does not fit the sensor's superpixel grid "
                f"({h}, {w}, 3)"
            ) from None
        if not np.isfinite(rad).all() or (rad < 0).any():
            raise ValueError("radiance_rgb must be finite and ≥ 0 W·sr⁻¹·m⁻²")
        return rad

    def mosaic_radiance(self, radiance_rgb: np.ndarray) -> np.ndarray:
        """Expand per-superpixel radiance (H/2×W/2×3) to the RGGB mosaic (H×W float64)."""
        rad = self._checked_radiance(radiance_rgb)
        out = np.empty((self.height, self.width))
        out[0::2, 0::2] = rad[..., 0]
        out[0::2, 1::2] = rad[..., 1]
        out[1::2, 0::2] = rad[..., 1]
        out[1::2, 1::2] = rad[..., 2]
        return out

    def expected_electrons(self, radiance_rgb: np.ndarray, exposure_s: float) -> np.ndarray:
        """Mean collected charge per pixel (H×W, e⁻) before shot noise and clipping."""
        mean = self.mosaic_radiance(radiance_rgb)
        mean *= self.response
        mean += self.dark_current_e_per_s
        mean *= exposure_s
        return mean

    def expose(
        self, radiance_rgb: np.ndarray, exposure_s: float, iso: float = 100.0, frame_seed: int = 0
    ) -> np.ndarray:
        """Simulate one raw frame.

        Parameters
        ----------
        radiance_rgb:
            Radiance per superpixel, (H/2)×(W/2)×3 (or broadcastable), W·sr⁻¹·m⁻².
        exposure_s:
            Exposure time, s (> 0).
        iso:
            ISO speed (> 0); the conversion gain scales as 100 / ISO.
        frame_seed:
            Seed (≥ 0) of this frame's noise, combined with the sensor's seed.

        Returns
        -------
        numpy.ndarray
            Raw mosaic (:attr:`raw_shape`, uint16, DN), RGGB, black level included: the active
            H×W area, preceded by the optical-black border if the sensor has one.
        """
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"exposure_s must be a finite time > 0 s, got {exposure_s}")
        if not (math.isfinite(iso) and iso > 0):
            raise ValueError(f"iso must be > 0, got {iso}")
        radiance = self._checked_radiance(radiance_rgb)
        out = np.empty(self.raw_shape, dtype=np.uint16)
        top, left, _, _ = self.active_area
        gain = self.gain_at(iso)
        expose_mosaic(radiance, self.response, frame_key(self.seed, frame_seed),
                      (top, left), self.dark_current_e_per_s, exposure_s, self.full_well_e, gain,
                      math.hypot(self.read_noise_e / gain, self.black_noise_dn),
                      float(self.black_level_dn), self.adc_max, out)
        return out
