"""One compiled pass from per-superpixel radiance to a raw mosaic: charge, shot noise, read
noise, gain, black level, ADC (the physics is :mod:`simulators.sensor`'s docstring).

Random numbers are counter-based (:mod:`simulators.counter_rng`): pixel p of a frame draws its
k-th uniform from the SplitMix64 mix of (frame key, p, k), so a frame depends only on its key
and is the same on any number of threads. Shot noise is Poisson(μ): drawn exactly below
:data:`EXACT_POISSON_BELOW_E` electrons (multiplication method below 10, Hörmann's transformed
rejection PTRS above), and above it as the normal limit round(μ + √μ·z), whose skewness 1/√μ
is under 0.032 there (mean and variance μ either way). Read noise is normal. Normals come from
the ziggurat (:mod:`simulators.ziggurat`: one draw, no transcendental function, most of the
time; Box–Muller's logarithm, sine and cosine took most of a pixel's time).
"""

from __future__ import annotations

import math

import numba
import numpy as np

import simulators.counter_rng as counter_rng
import simulators.ziggurat as ziggurat
from drivers.numba_cache import drop_stale_cache
from simulators.counter_rng import GAMMA, frame_key, mix, uniform
from simulators.ziggurat import normal

drop_stale_cache(__file__, (counter_rng.__file__, ziggurat.__file__))  # compiled in

__all__ = ["EXACT_POISSON_BELOW_E", "expose_mosaic", "frame_key"]

EXACT_POISSON_BELOW_E = 1000.0
"""Expected charge (e⁻) under which shot noise is drawn from the exact Poisson law."""


@numba.njit(cache=True)
def _poisson_small(mu: float, limit: float, stream: np.uint64, k: int) -> tuple[float, int]:
    """Poisson(μ < 10) by multiplying uniforms (Knuth) down to ``limit`` = exp(−μ); returns
    (count, next draw index)."""
    count = 0.0
    product = uniform(stream, k)
    k += 1
    while product > limit:
        count += 1.0
        product *= uniform(stream, k)
        k += 1
    return count, k


@numba.njit(cache=True)
def _poisson_ptrs(mu: float, stream: np.uint64, k: int) -> tuple[float, int]:
    """Poisson(μ ≥ 10) by transformed rejection with squeeze (Hörmann 1993, PTRS)."""
    slam = math.sqrt(mu)
    loglam = 0.0  # log μ (> 2.3), computed when a draw first needs it: most never do
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    inv_alpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    while True:
        u = uniform(stream, k) - 0.5
        v = uniform(stream, k + 1)
        k += 2
        us = 0.5 - abs(u)
        count = math.floor((2.0 * a / us + b) * u + mu + 0.43)
        if us >= 0.07 and v <= vr:
            return count, k
        if count < 0.0 or (us < 0.013 and v > us):
            continue
        if loglam == 0.0:
            loglam = math.log(mu)
        if (math.log(v) + math.log(inv_alpha) - math.log(a / (us * us) + b)
                <= -mu + count * loglam - math.lgamma(count + 1.0)):
            return count, k


@numba.njit(cache=True, inline="always")
def _pixel_dn(mu: float, limit: float, stream: np.uint64, full_well_e: float, inv_gain: float,
              sigma_dn: float, black_dn: float, adc_max: float) -> float:
    """One pixel's raw value (DN) for an expected charge ``mu`` (e⁻); ``limit`` = exp(−μ)
    (used below 10 e⁻)."""
    read, k = normal(stream, 0)
    if mu >= EXACT_POISSON_BELOW_E:
        charge = max(math.floor(mu + math.sqrt(mu) * normal(stream, k)[0] + 0.5), 0.0)
    elif mu >= 10.0:
        charge = _poisson_ptrs(mu, stream, k)[0]
    else:
        charge = _poisson_small(mu, limit, stream, k)[0]
    dn = min(charge, full_well_e) * inv_gain + sigma_dn * read + black_dn
    return min(max(math.floor(dn + 0.5), 0.0), adc_max)


PARALLEL_MIN_PIXELS = 1 << 18
"""Mosaics of fewer pixels are exposed on one thread: waking numba's thread pool costs more
than it saves on them (the example rigs' 192 × 128 frames)."""


def expose_mosaic(radiance: np.ndarray, response: np.ndarray, key: np.uint64,
                  active: tuple[int, int], dark_e_per_s: float, exposure_s: float,
                  full_well_e: float, gain_e_per_dn: float, sigma_dn: float,
                  black_dn: float, adc_max: int, out: np.ndarray) -> None:
    """Fill ``out`` (raw rows × columns, uint16 DN) with one exposed RGGB frame.

    ``radiance`` is (H/2, W/2, 3) W·sr⁻¹·m⁻² per superpixel of the active area, whose top-left
    pixel sits at ``active`` = (top, left) of ``out``; ``response`` (H, W) is each active
    pixel's e⁻ per (W·sr⁻¹·m⁻² · s). Pixels outside the active area collect dark current only.
    Rows go to numba's thread pool on mosaics of :data:`PARALLEL_MIN_PIXELS` or more.
    """
    kernel = _expose_parallel if out.size >= PARALLEL_MIN_PIXELS else _expose_serial
    kernel(radiance, response, key, active, dark_e_per_s, exposure_s, full_well_e,
           gain_e_per_dn, sigma_dn, black_dn, adc_max, out)


@numba.njit(parallel=True, cache=True, nogil=True)
def _expose_parallel(radiance, response, key, active, dark_e_per_s, exposure_s, full_well_e,
                     gain_e_per_dn, sigma_dn, black_dn, adc_max, out):  # pragma: no cover
    """:func:`expose_mosaic`, its rows on numba's thread pool."""
    for r in numba.prange(out.shape[0]):
        _expose_row(r, radiance, response, key, active, dark_e_per_s, exposure_s,
                    full_well_e, gain_e_per_dn, sigma_dn, black_dn, adc_max, out)


@numba.njit(cache=True, nogil=True)
def _expose_serial(radiance, response, key, active, dark_e_per_s, exposure_s, full_well_e,
                   gain_e_per_dn, sigma_dn, black_dn, adc_max, out):  # pragma: no cover
    """:func:`expose_mosaic` on the calling thread."""
    for r in range(out.shape[0]):
        _expose_row(r, radiance, response, key, active, dark_e_per_s, exposure_s,
                    full_well_e, gain_e_per_dn, sigma_dn, black_dn, adc_max, out)


@numba.njit(cache=True, inline="always")
def _expose_row(r, radiance, response, key, active, dark_e_per_s, exposure_s, full_well_e,
                gain_e_per_dn, sigma_dn, black_dn, adc_max, out):  # pragma: no cover
    """Raw row ``r`` of :func:`expose_mosaic`."""
    cols = out.shape[1]
    top, left = active
    height, width = response.shape
    cap = 4.0 * full_well_e + 1e3  # beyond the full well all clips: keeps the draws finite
    inv_gain = 1.0 / gain_e_per_dn
    ar = r - top
    last_mu = -1.0
    limit = 1.0
    for c in range(cols):
        ac = c - left
        mu = dark_e_per_s
        if 0 <= ar < height and 0 <= ac < width:
            colour = (ar & 1) + (ac & 1)  # RGGB: R 0, G 1, B 2
            mu += radiance[ar >> 1, ac >> 1, colour] * response[ar, ac]
        stream = mix(key ^ (np.uint64(r * cols + c) * GAMMA))
        mu = min(mu * exposure_s, cap)
        if mu != last_mu and not mu >= 10.0:  # exp(−μ) once per run of equal μ (dark pixels)
            last_mu = mu
            limit = math.exp(-mu)
        out[r, c] = np.uint16(_pixel_dn(mu, limit, stream, full_well_e,
                                        inv_gain, sigma_dn, black_dn, float(adc_max)))
