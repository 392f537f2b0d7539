"""A 2D sample warp by marginal and conditional inversion of a bilinear density, in numpy.

The density is the bilinear interpolant of values on a regular W × H grid over [0, 1]² (columns
x, rows y), optionally conditioned on parameters: the data are shaped ``(*param_res, H, W)``
and every table is interpolated linearly between the parameter values it was given at. The
warp (:meth:`Marginal2D.sample`) draws y from the continuous marginal (the density integrated
over x, piecewise linear in y), then x from the conditional given y; :meth:`Marginal2D.invert`
is its inverse, :meth:`Marginal2D.eval` the interpolated density. This is the construction of
Dupuy & Jakob 2018 (the RGL-EPFL material format), written from the paper's description and
the format's public documentation; the arithmetic follows the published reference, so a
``.bsdf`` file evaluates here as it does in a renderer using that reference.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

EPSILON = 2.0 ** -24
"""Samples are kept in [ε, 1 − ε] (single-precision machine epsilon)."""

Corners = list[tuple[np.ndarray, np.ndarray]]
"""(slice index, weight) of each corner of the parameter cell, one entry per point."""


def _lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    return a + (b - a) * t


def _bisect(start: int, end: int, below: Callable[[np.ndarray], np.ndarray], n: int) -> np.ndarray:
    """First index in [start, end] where ``below(index)`` is False (``end`` if none), per point."""
    lo = np.full(n, start, dtype=np.int64)
    hi = np.full(n, end, dtype=np.int64)
    steps = int(np.log2(end - start)) + 1 if end > start else 0
    for _ in range(steps):
        mid = (lo + hi) >> 1
        go = below(mid)
        lo = np.where(go, np.minimum(mid + 1, hi), lo)
        hi = np.where(go, hi, mid)
    return lo


def sample_segment(u: np.ndarray, inv_width: float, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Fraction t of a segment whose linear density goes v0 → v1 at which the integral is u."""
    non_const = np.abs(v0 - v1) > 1e-4 * (v0 + v1)
    divisor = np.where(non_const, v0 - v1, v0 + v1)
    u = u * 2.0 * inv_width
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(non_const, v0 - np.sqrt(np.maximum(v0 * v0 + u * (v1 - v0), 0.0)), u)
        return np.where(divisor != 0, u / np.where(divisor != 0, divisor, 1.0), u)


def invert_segment(t: np.ndarray, width: float, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Integral of the segment's linear density v0 → v1 up to the fraction t."""
    return t * _lerp(v0, v1, 0.5 * t) * width


class Marginal2D:
    """Continuous marginal/conditional warp of a bilinear density (module docstring).

    Parameters
    ----------
    data
        Values shaped ``(*param_res, H, W)``, H, W ≥ 2, non-negative.
    param_values
        One increasing array per parameter axis (its length that axis's size).
    normalize
        Scale each slice to integrate to 1 over [0, 1]² (densities); else keep the values.
    sampling
        Build the CDFs for :meth:`sample` and :meth:`invert` (else only :meth:`eval` works).
    """

    def __init__(self, data: np.ndarray, param_values: Sequence[np.ndarray] = (), *,
                 normalize: bool = True, sampling: bool = True) -> None:
        data = np.asarray(data, dtype=np.float64)
        self.params = [np.asarray(v, dtype=np.float64).reshape(-1) for v in param_values]
        res = tuple(v.size for v in self.params)
        if data.ndim != 2 + len(res) or data.shape[:-2] != res or min(data.shape[-2:]) < 2:
            raise ValueError(f"data shaped {data.shape} do not match parameters {res} × H × W ≥ 2")
        self.height, self.width = data.shape[-2:]
        h, w = self.height, self.width
        self.strides = [int(np.prod(res[k + 1:], dtype=np.int64)) for k in range(len(res))]
        slices = data.reshape(-1, h, w)
        self.normalized = normalize
        self.sampling = sampling
        if sampling:
            cond = np.cumsum(0.5 / (w - 1) * (slices[:, :, :-1] + slices[:, :, 1:]), axis=2)
            rows = cond[:, :, -1]
            marg = np.cumsum(0.5 / (h - 1) * (rows[:, :-1] + rows[:, 1:]), axis=1)
            norm = 1.0 / marg[:, -1] if normalize else np.ones(len(slices))
            self.cond = (cond * norm[:, None, None]).reshape(len(slices), -1)
            self.marg = marg * norm[:, None]
        else:
            total = (slices[:, :-1, :-1] + slices[:, :-1, 1:] + slices[:, 1:, :-1]
                     + slices[:, 1:, 1:]).sum(axis=(1, 2)) * 0.25 / ((w - 1) * (h - 1))
            norm = 1.0 / total if normalize else np.ones(len(slices))
        self.data = (slices * norm[:, None, None]).reshape(len(slices), -1)

    # ------------------------------------------------------------------ parameters
    def corners(self, params: np.ndarray | None, n: int) -> Corners:
        """The slices to interpolate between and their weights, for ``n`` points whose
        parameters are the rows of ``params`` (clamped to each axis's range)."""
        out: Corners = [(np.zeros(n, dtype=np.int64), np.ones(n))]
        for k, values in enumerate(self.params):
            if values.size == 1:
                continue
            p = np.broadcast_to(np.asarray(params, dtype=np.float64)[..., k], (n,))
            idx = np.clip(np.searchsorted(values, p, side="left"), 1, values.size - 1) - 1
            v0, v1 = values[idx], values[idx + 1]
            w1 = np.clip((p - v0) / (v1 - v0), 0.0, 1.0)
            step = self.strides[k]
            out = [(s + step * (idx + b), wt * (w1 if b else 1.0 - w1))
                   for s, wt in out for b in (0, 1)]
        return out

    @staticmethod
    def _lookup(table: np.ndarray, index: np.ndarray, corners: Corners) -> np.ndarray:
        return sum(wt * table[s, index] for s, wt in corners)  # type: ignore[return-value]

    # ------------------------------------------------------------------ warps
    def eval(self, pos: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """The interpolated density (or values) at points ``pos`` (N, 2) in [0, 1]²."""
        pos = np.clip(np.asarray(pos, dtype=np.float64), 0.0, 1.0)
        c = self.corners(params, len(pos))
        w, h = self.width, self.height
        fx, fy = pos[:, 0] * (w - 1), pos[:, 1] * (h - 1)
        ix = np.minimum(fx.astype(np.int64), w - 2)
        iy = np.minimum(fy.astype(np.int64), h - 2)
        fx, fy = fx - ix, fy - iy
        i = iy * w + ix
        v00, v10 = self._lookup(self.data, i, c), self._lookup(self.data, i + 1, c)
        v01, v11 = self._lookup(self.data, i + w, c), self._lookup(self.data, i + w + 1, c)
        return _lerp(_lerp(v00, v10, fx), _lerp(v01, v11, fx), fy)

    def sample(self, u: np.ndarray, params: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Warp uniform points ``u`` (N, 2) to the density: (points (N, 2), density)."""
        self._need_sampling()
        u = np.clip(np.asarray(u, dtype=np.float64), EPSILON, 1.0 - EPSILON)
        n, w, h = len(u), self.width, self.height
        c = self.corners(params, n)
        x, y = u[:, 0].copy(), u[:, 1].copy()
        if not self.normalized:
            y *= self._lookup(self.marg, np.full(n, h - 2), c)
        row = _bisect(0, h - 2, lambda i: self._lookup(self.marg, i, c) < y, n)
        y -= np.where(row > 0, self._lookup(self.marg, np.maximum(row - 1, 0), c), 0.0)
        base = row * (w - 1)
        r0 = self._lookup(self.cond, base + w - 2, c)
        r1 = self._lookup(self.cond, base + 2 * (w - 1) - 1, c)
        fy = sample_segment(y, h - 1, r0, r1)
        x *= _lerp(r0, r1, fy)

        def conditional(i: np.ndarray) -> np.ndarray:
            return _lerp(self._lookup(self.cond, base + i, c),
                         self._lookup(self.cond, base + i + w - 1, c), fy)

        col = np.minimum(_bisect(0, w - 1, lambda i: conditional(i) < x, n), w - 2)
        x -= np.where(col > 0, conditional(np.maximum(col - 1, 0)), 0.0)
        i = row * w + col
        c0 = _lerp(self._lookup(self.data, i, c), self._lookup(self.data, i + w, c), fy)
        c1 = _lerp(self._lookup(self.data, i + 1, c), self._lookup(self.data, i + w + 1, c), fy)
        fx = sample_segment(x, w - 1, c0, c1)
        pts = np.stack([(col + fx) / (w - 1), (row + fy) / (h - 1)], axis=-1)
        return pts, _lerp(c0, c1, fx)

    def invert(self, pos: np.ndarray, params: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """The uniform points :meth:`sample` maps to ``pos`` (N, 2), and the density there."""
        self._need_sampling()
        pos = np.clip(np.asarray(pos, dtype=np.float64), 0.0, 1.0)
        n, w, h = len(pos), self.width, self.height
        c = self.corners(params, n)
        fx, fy = pos[:, 0] * (w - 1), pos[:, 1] * (h - 1)
        ix = np.minimum(fx.astype(np.int64), w - 2)
        iy = np.minimum(fy.astype(np.int64), h - 2)
        fx, fy = fx - ix, fy - iy
        i = iy * w + ix
        c0 = _lerp(self._lookup(self.data, i, c), self._lookup(self.data, i + w, c), fy)
        c1 = _lerp(self._lookup(self.data, i + 1, c), self._lookup(self.data, i + w + 1, c), fy)
        pdf = _lerp(c0, c1, fx)
        x = invert_segment(fx, 1.0 / (w - 1), c0, c1)
        base = iy * (w - 1)
        prev = np.maximum(ix - 1, 0)
        x += np.where(ix > 0, _lerp(self._lookup(self.cond, base + prev, c),
                                    self._lookup(self.cond, base + prev + w - 1, c), fy), 0.0)
        r0 = self._lookup(self.cond, base + w - 2, c)
        r1 = self._lookup(self.cond, base + 2 * (w - 1) - 1, c)
        with np.errstate(invalid="ignore", divide="ignore"):
            x = x / _lerp(r0, r1, fy)
        y = invert_segment(fy, 1.0 / (h - 1), r0, r1)
        y += np.where(iy > 0, self._lookup(self.marg, np.maximum(iy - 1, 0), c), 0.0)
        if not self.normalized:
            y /= self._lookup(self.marg, np.full(n, h - 2), c)
        return np.stack([x, y], axis=-1), pdf

    def _need_sampling(self) -> None:
        if not self.sampling:
            raise ValueError("this Marginal2D was built without sampling tables")
