"""Counter-based random numbers for the simulated sensor: a pixel's k-th draw is the SplitMix64
mix of (its stream, k), so a frame depends only on its key, never on the order or the number of
threads that compute it (:mod:`simulators.exposure`)."""

from __future__ import annotations

import numba
import numpy as np

GAMMA = np.uint64(0x9E3779B97F4A7C15)
"""SplitMix64's increment (2⁶⁴ / golden ratio)."""
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def frame_key(sensor_seed: int, frame_seed: int) -> np.uint64:
    """The 64-bit key of one frame's noise, from (sensor seed, frame seed)."""
    return np.random.SeedSequence([sensor_seed, frame_seed]).generate_state(1, np.uint64)[0]


@numba.njit(cache=True, inline="always")
def mix(z: np.uint64) -> np.uint64:
    """SplitMix64's output function: a bijective scramble of 64 bits."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def draw_bits(stream: np.uint64, k: int) -> np.uint64:
    """The k-th 64 random bits of a pixel's stream."""
    return mix(stream + np.uint64(k + 1) * GAMMA)


@numba.njit(cache=True, inline="always")
def uniform(stream: np.uint64, k: int) -> float:
    """The k-th uniform of a pixel's stream, in the open interval (0, 1)."""
    return (float(draw_bits(stream, k) >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
