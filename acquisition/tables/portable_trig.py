"""``atan2`` and ``acos`` from + − × / and √ alone: the same bits on any IEEE-754 machine, and
loops that call them vectorise (SIMD).

libm's ``atan2`` is a scalar call: a loop over samples that calls it cannot be vectorised, and
its last bit is the C library's (glibc, musl, macOS and Windows differ). These functions use
only correctly rounded operations in a fixed order, with no fast-math (no FMA contraction, no
reassociation), so a compiled loop gives the same bits on every CPU and every libm, scalar or
vectorised, and LLVM vectorises the loops that call them (``inline="always"``).

``atan2(y, x)``: the octant is reduced to t = min(|x|, |y|) / max(|x|, |y|) ∈ [0, 1], then to
u ∈ [−tan(π/8), tan(π/8)] (u = (t − 1)/(t + 1) above tan(π/8), adding π/4), and
atan(u) = u + u·(z·P(z)), z = u², with P of degree 10: a Chebyshev least-squares fit of
(atan(√z)/√z − 1)/z on [0, tan²(π/8)] (targets from the series in 60-digit decimal), whose
error (below 1e-16) is far under the rounding of the last additions. It stays within 3 ulp of
the correctly rounded value (``tests/test_portable_trig.py`` measures it against ``math``).
Conventions as C's: atan2(±0, +0) = ±0, atan2(±0, −0) = ±π, the sign of y; NaN in, NaN out;
both arguments infinite gives NaN (C gives odd multiples of π/4).

``acos(c) = atan2(√((1 − c)(1 + c)), c)`` for c ∈ [−1, 1] (NaN outside): 1 − c and 1 + c are
exact where they matter (Sterbenz), so small angles keep their relative accuracy.
"""

from __future__ import annotations

import math
import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels

from numba import njit  # noqa: E402

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}

TAN_PI_8 = math.sqrt(2.0) - 1.0
"""tan(π/8), where the reduction switches to (t − 1)/(t + 1)."""
P0, P1, P2, P3 = (-0.33333333333333326, 0.19999999999994933, -0.14285714284536014,
                  0.1111111100431435)
P4, P5, P6, P7 = (-0.09090904128982406, 0.0769217278143436, -0.06664365778040121,
                  0.05856893571133389)
P8, P9, P10 = -0.050789382355487536, 0.03904533673345907, -0.018951056205811972
"""P(z), lowest degree first (module docstring)."""
_PI = math.pi
_PI_2 = math.pi / 2.0
_PI_4 = math.pi / 4.0


@njit(inline="always", **_JIT)
def _atan_reduced(u):  # pragma: no cover - compiled
    """atan(u) for |u| ≤ tan(π/8)."""
    z = u * u
    p = ((((((((((P10 * z + P9) * z + P8) * z + P7) * z + P6) * z + P5) * z + P4) * z + P3)
            * z + P2) * z + P1) * z + P0)
    return u + u * (z * p)


@njit(inline="always", **_JIT)
def atan2(y, x):  # pragma: no cover - compiled
    """The angle (rad) of (x, y) in [−π, π], within 3 ulp (module docstring)."""
    ax = abs(x)
    ay = abs(y)
    swap = ay > ax
    num = ax if swap else ay
    den = ay if swap else ax
    t = num / den if den > 0.0 else 0.0
    big = t > TAN_PI_8
    u = (t - 1.0) / (t + 1.0) if big else t
    r = _atan_reduced(u)
    r = _PI_4 + r if big else r
    r = _PI_2 - r if swap else r
    r = _PI - r if math.copysign(1.0, x) < 0.0 else r
    r = math.copysign(r, y)
    return r if (x == x and y == y) else math.nan


@njit(inline="always", **_JIT)
def acos(c):  # pragma: no cover - compiled
    """arccos(c) (rad) for c ∈ [−1, 1]; NaN outside."""
    s = math.sqrt((1.0 - c) * (1.0 + c))
    return atan2(s, c) if (c >= -1.0 and c <= 1.0) else math.nan
