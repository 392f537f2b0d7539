"""Exact, associative sums: float64 values as fixed-point integers in three int64 limbs.

A value v is held as the integer V = round(v · 2^88) (quantum 2^-88 ≈ 3.2e-27), split into
limbs of :data:`LIMB_BITS` = 44 bits: V = l₂·2^88 + l₁·2^44 + l₀. Summing values is summing
limbs, integer addition, so a sum does not depend on how the values were split, ordered or
grouped; it is rounded to float64 once, when read (:func:`to_float`, correctly rounded).

Conversion (:func:`to_limbs`): with a = |v|, l₂ = ⌊a⌋, r = (a − l₂)·2^44, l₁ = ⌊r⌋,
l₀ = rint((r − l₁)·2^44) (ties to even), each limb negated for a negative v. Every step but the
last rint is exact in IEEE double, so a value converts exactly when its lowest set bit is
≥ 2^-88: any |v| ≥ 2^-36 ≈ 1.5e-11. Smaller values are rounded to the quantum, the same way
every time (BRDF values, variances, angles and their products sit far above it). The numba
kernels reach the same integer another way (:mod:`acquisition.tables.exact_kernels`: three
parts at fixed binary points, summed exactly in float64 over a run of samples).

Range: a summed value must have |v| < :data:`VALUE_LIMIT` = 2^40 ≈ 1.1e12 (so BRDF samples
|x| < 2^20 ≈ 1.05e6 sr⁻¹, whose squares are summed too, and angles |θ| < 2^20 degrees);
anything larger raises :class:`OutOfRangeError` before a sum changes, it never wraps.

Lazy carries: the limbs of a running sum are plain int64 additions; the lower two are brought
back into [0, 2^44) (:func:`normalize`, the carry pass) at least every :data:`CARRY_EVERY`
= 2^18 additions to a bin, before they could overflow (2^18 · 2^44 = 2^62). The top limb is
signed and takes the carries; a sum whose top limb reaches 2^61 (|Σ| ≥ 2.3e18) raises too.
Normalised limbs are the canonical form: equal sums have equal limbs.
"""

from __future__ import annotations

import numpy as np

from drivers.errors import GonioError

LIMBS = 3
"""Limbs per value (int64 each)."""
LIMB_BITS = 44
"""Payload bits of the two lower limbs."""
FRACTION_BITS = 2 * LIMB_BITS
"""The quantum is 2^-FRACTION_BITS."""
VALUE_LIMIT = 2.0**40
"""Largest |value| (exclusive) one addition may bring."""
SET_LIMIT = 2.0**61
"""Largest |value| (exclusive) a whole sum may be set to (from stored statistics)."""
CARRY_EVERY = 1 << 18
"""Additions to one bin between two carry passes, at most."""
TOP_LIMIT = 1 << 61
"""A normalised top limb at or past this magnitude is an overflow."""
_SCALE = float(2**LIMB_BITS)
_MASK = (1 << LIMB_BITS) - 1


class OutOfRangeError(GonioError, ValueError):
    """A value is too large for the exact accumulator (or a sum overflows it)."""


def check_range(values: np.ndarray, limit: float, what: str, unit: str,
                largest: float | None = None) -> None:
    """Raise :class:`OutOfRangeError` when a finite entry of ``values`` has |v| ≥ ``limit``
    (non-finite ones are the callers' to drop); ``largest``: that maximum, if known."""
    largest = max_finite_abs(values) if largest is None else largest
    if largest >= limit:
        raise OutOfRangeError(
            f"{what} {largest:.6g}{unit} is outside the exact accumulator's range "
            f"(|v| < {limit:.13g}{unit}): check the calibration and the white reference's scale"
        )


def max_finite_abs(values: np.ndarray) -> float:
    """Largest |v| over the finite entries (0 for none)."""
    a = np.abs(np.asarray(values, dtype=np.float64))
    if a.size == 0:
        return 0.0
    largest = float(a.max())
    if np.isfinite(largest):
        return largest
    finite = a[np.isfinite(a)]
    return float(finite.max()) if finite.size else 0.0


def to_limbs(values: np.ndarray) -> np.ndarray:
    """Signed limbs of each value, ``values.shape + (3,)`` int64, low limb first (not
    normalised for negative values: each limb carries the value's sign). The caller checks the
    range (:func:`check_range`); values must be finite."""
    return np.moveaxis(limbs_first(values), 0, -1)


def limbs_first(values: np.ndarray) -> np.ndarray:
    """:func:`to_limbs` with the limb axis first, ``(3,) + values.shape`` (each limb
    contiguous: what the numpy path sums)."""
    v = np.asarray(values, dtype=np.float64)
    a = np.abs(v)
    out = np.empty((LIMBS,) + v.shape, np.int64)
    t = np.floor(a)
    out[2] = t
    a -= t
    a *= _SCALE
    np.floor(a, out=t)
    out[1] = t
    a -= t
    a *= _SCALE
    np.rint(a, out=a)
    out[0] = a
    negative = v < 0.0
    if negative.any():
        np.negative(out, out=out, where=negative)
    return out


def normalize(limbs: np.ndarray) -> np.ndarray:
    """Carry pass in place over ``(..., 3)`` limbs: the lower two into [0, 2^44), the carries
    into the signed top limb. Raises :class:`OutOfRangeError` when a top limb overflows.
    Returns ``limbs``."""
    for k in range(LIMBS - 1):
        carry = limbs[..., k] >> LIMB_BITS
        limbs[..., k] &= _MASK
        limbs[..., k + 1] += carry
    top = limbs[..., LIMBS - 1]
    if top.size and (top.max() >= TOP_LIMIT or top.min() <= -TOP_LIMIT):
        raise OutOfRangeError(
            "a bin's exact sum overflowed (|Σ| ≥ 2.3e18): split the data into several tables"
        )
    return limbs


def to_float(limbs: np.ndarray) -> np.ndarray:
    """The float64 nearest each sum (ties to even), ``limbs.shape[:-1]``: one rounding, from
    the exact value. ``limbs`` may be unnormalised; it is not modified."""
    m = normalize(np.array(limbs, dtype=np.int64, copy=True))
    negative = m[..., 2] < 0
    np.negative(m, out=m, where=negative[..., None])
    normalize(m)  # the magnitude: top limb ≥ 0
    pieces = np.stack([m[..., 0], m[..., 1], m[..., 2] & _MASK, m[..., 2] >> LIMB_BITS])
    k = np.where(pieces[3] != 0, 3, np.where(pieces[2] != 0, 2, np.where(pieces[1] != 0, 1, 0)))
    top = np.take_along_axis(pieces, k[None], 0)[0]
    below = np.take_along_axis(pieces, np.maximum(k - 1, 0)[None], 0)[0] * (k >= 1)
    third = np.take_along_axis(pieces, np.maximum(k - 2, 0)[None], 0)[0] * (k >= 2)
    rest = (pieces[0] != 0) & (k >= 3)  # any bit below the third piece (k = 3 only)
    bits = np.frexp(top.astype(np.float64))[1].astype(np.int64)  # bit length, 0 for 0
    mantissa = _round_top(top, below, third, rest, bits)
    exponent = LIMB_BITS * k + bits - 53 - FRACTION_BITS
    out = np.ldexp(mantissa.astype(np.float64), exponent.astype(np.int32))
    out[top == 0] = 0.0
    return np.where(negative, -out, out)


def _round_top(top: np.ndarray, below: np.ndarray, third: np.ndarray, rest: np.ndarray,
               bits: np.ndarray) -> np.ndarray:
    """The 53 leading bits of the magnitude (top piece of ``bits`` bits, then the 44-bit
    pieces ``below`` and ``third``, ``rest`` true when anything lower is set), rounded to
    nearest, ties to even (may carry into 2^53)."""
    wide = bits >= 10  # the top and the next piece hold the 54 leading bits
    s_below = np.clip(bits - 10, 0, 63)
    s_up = np.clip(10 - bits, 0, 63)
    s_third = np.clip(34 + bits, 0, 63)
    lead = top << np.clip(54 - bits, 0, 63)
    t_wide = lead | (below >> s_below)
    t_narrow = lead | (below << s_up) | (third >> s_third)
    r_wide = (below & ((1 << s_below) - 1)) | third
    r_narrow = third & ((1 << s_third) - 1)
    t54 = np.where(wide, t_wide, t_narrow)
    sticky = (np.where(wide, r_wide, r_narrow) != 0) | rest
    mantissa = t54 >> 1
    round_bit = (t54 & 1) == 1
    up = round_bit & (sticky | ((mantissa & 1) == 1))
    return mantissa + up
