"""Standard normal draws by Marsaglia and Tsang's ziggurat (2000) on the counter-based stream
of :mod:`simulators.counter_rng`: one 64-bit draw gives a normal over 98 % of the time, with no
transcendental function (the simulated sensor's read noise and large-charge shot noise).

The half-density f(x) = exp(−x²/2) is covered by :data:`LAYERS` layers of equal area ``V``:
layer i ≥ 1 the rectangle [0, X[i]] × [f(X[i]), f(X[i+1])], layer 0 the rectangle
[0, R] × [0, f(R)] plus the tail beyond R = X[1] (X[0] = V / f(R) makes it a rectangle of
the same area). A draw picks a layer (8 bits), a sign (1 bit) and u ∈ [0, 1) (53 bits):
x = u·X[i] is returned at once when x < X[i+1] (under the curve at any height of the layer);
otherwise layer 0 samples the tail (Marsaglia 1964) and the others accept x when a uniform
height in the layer falls under f(x), else draw again. Layer, sign and u come from disjoint
bits of the draw, so they are independent (Doornik 2005's caveat about the original).
"""

from __future__ import annotations

import math

import numba
import numpy as np

import simulators.counter_rng as counter_rng
from drivers.numba_cache import drop_stale_cache
from simulators.counter_rng import draw_bits, uniform

drop_stale_cache(__file__, (counter_rng.__file__,))  # its draws are compiled in

LAYERS = 256
R = 3.6541528853610088
"""Where the tail starts (for 256 layers)."""
V = 0.00492867323399
"""Each layer's area (for 256 layers)."""


def _edges() -> np.ndarray:
    """X[0 … LAYERS] (module docstring), decreasing to X[LAYERS] = 0."""
    x = np.empty(LAYERS + 1)
    x[0], x[1] = V / math.exp(-0.5 * R * R), R
    for i in range(1, LAYERS):
        height = math.exp(-0.5 * x[i] * x[i]) + V / x[i]
        x[i + 1] = math.sqrt(-2.0 * math.log(height)) if height < 1.0 else 0.0
    x[LAYERS] = 0.0
    return x


X = _edges()
F = np.exp(-0.5 * X * X)
"""f at each edge (F[0] is not a height: layer 0 starts at 0)."""
_LAYER_MASK = np.uint64(LAYERS - 1)
_SIGN_BIT = np.uint64(LAYERS)
_SCALE = 1.0 / 9007199254740992.0  # 2⁻⁵³


@numba.njit(cache=True, inline="always")
def normal(stream: np.uint64, k: int) -> tuple[float, int]:
    """A standard normal from the stream's draws k, k + 1, …; returns it and the next draw
    index (k + 1 most of the time)."""
    while True:
        bits = draw_bits(stream, k)
        k += 1
        i = int(bits & _LAYER_MASK)
        sign = -1.0 if bits & _SIGN_BIT else 1.0
        x = float(bits >> np.uint64(11)) * _SCALE * X[i]
        if x < X[i + 1]:
            return sign * x, k
        if i == 0:  # the tail beyond R
            while True:
                t = -math.log(uniform(stream, k)) / R
                y = -math.log(uniform(stream, k + 1))
                k += 2
                if y + y > t * t:
                    return sign * (R + t), k
        height = F[i] + uniform(stream, k) * (F[i + 1] - F[i])
        k += 1
        if height < math.exp(-0.5 * x * x):
            return sign * x, k
