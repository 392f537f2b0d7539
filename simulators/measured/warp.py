"""Tables on the unit square for the RGL ``.bsdf`` evaluation (Dupuy & Jakob 2018): bilinear
interpolation, optionally conditioned on parameters, and the inverse of the continuous
marginal/conditional warp of such a density, as Mitsuba 3's ``Marginal2D`` defines them.

A table holds values on a regular H × W grid over [0, 1]² (x across the W columns, y down
the H rows), one grid per combination of parameter values (data shaped ``(*param_sizes, H, W)``);
between parameter values every quantity read from the grids is interpolated linearly (a
parameter beyond its range takes the end value).

The warp maps [0, 1]² onto itself so that uniform points come out distributed like the
density: y from the marginal (the density integrated over x), then x from the conditional
at that y. Both are integrals of the bilinear interpolant, so the map is continuous;
:meth:`MarginalWarp.invert` sends a point back to the uniform square.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np


class BilinearTable:
    """Values on the unit square, interpolated bilinearly (and linearly in the parameters)."""

    def __init__(self, data: np.ndarray, param_values: Sequence[np.ndarray] = ()) -> None:
        data = np.asarray(data, dtype=np.float64)
        self.axes = [np.asarray(v, dtype=np.float64).ravel() for v in param_values]
        sizes = tuple(a.size for a in self.axes)
        if data.shape[:-2] != sizes or min(data.shape[-2:]) < 2:
            raise ValueError(f"a table shaped {data.shape} does not match parameters {sizes} "
                             "and a grid of at least 2 × 2")
        self.rows, self.cols = data.shape[-2:]
        self.grids = data.reshape(-1, self.rows * self.cols)

    def slice_weights(self, params: np.ndarray | None, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """(flat grid index, weight) per corner of each point's parameter cell; ``params``
        (n, number of parameters)."""
        per_axis = []
        for k, values in enumerate(self.axes):
            if values.size == 1:
                per_axis.append(((np.zeros(n, np.int64), np.ones(n)),))
                continue
            p = np.asarray(params, dtype=np.float64)[:, k]
            lower = np.clip(np.searchsorted(values, p, side="left") - 1, 0, values.size - 2)
            t = np.clip((p - values[lower]) / (values[lower + 1] - values[lower]), 0.0, 1.0)
            per_axis.append(((lower, 1.0 - t), (lower + 1, t)))
        strides = [int(np.prod([a.size for a in self.axes[k + 1:]], dtype=np.int64))
                   for k in range(len(self.axes))]
        corners = []
        for choice in itertools.product(*per_axis):
            index = sum((i * s for (i, _), s in zip(choice, strides, strict=True)),
                        np.zeros(n, np.int64))
            weight = np.prod([w for _, w in choice], axis=0) if choice else np.ones(n)
            corners.append((index, weight))
        return corners

    @staticmethod
    def gather(table: np.ndarray, corners: list[tuple[np.ndarray, np.ndarray]],
               at: np.ndarray) -> np.ndarray:
        """``table[slice, at]`` interpolated over the parameter cell's corners."""
        return sum(w * table[s, at] for s, w in corners)  # type: ignore[return-value]

    def cell(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(column, row) of the grid cell holding each point (n, 2), and the point's
        fractions (fx, fy) across it."""
        pos = np.clip(np.asarray(pos, dtype=np.float64), 0.0, 1.0)
        gx, gy = pos[:, 0] * (self.cols - 1), pos[:, 1] * (self.rows - 1)
        col = np.minimum(np.floor(gx), self.cols - 2).astype(np.int64)
        row = np.minimum(np.floor(gy), self.rows - 2).astype(np.int64)
        return col, row, gx - col, gy - row

    def corners_of_cell(self, col: np.ndarray, row: np.ndarray,
                        corners: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, ...]:
        """Values at the cell's (left top, right top, left bottom, right bottom) nodes."""
        top = row * self.cols + col
        bottom = top + self.cols
        return tuple(self.gather(self.grids, corners, at)
                     for at in (top, top + 1, bottom, bottom + 1))

    def eval(self, pos: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """The interpolated value at each point ``pos`` (n, 2) in [0, 1]²."""
        corners = self.slice_weights(params, len(pos))
        col, row, fx, fy = self.cell(pos)
        lt, rt, lb, rb = self.corners_of_cell(col, row, corners)
        return (1 - fy) * ((1 - fx) * lt + fx * rt) + fy * ((1 - fx) * lb + fx * rb)


class MarginalWarp(BilinearTable):
    """A bilinear density's continuous marginal/conditional warp (module docstring); each
    parameter slice is normalised to integrate to 1."""

    def __init__(self, data: np.ndarray, param_values: Sequence[np.ndarray] = ()) -> None:
        super().__init__(data, param_values)
        grids = self.grids.reshape(-1, self.rows, self.cols)
        # Integrals in units of one grid cell (the cell size cancels in every ratio below).
        along_rows = np.concatenate([np.zeros((len(grids), self.rows, 1)),
                                     np.cumsum((grids[:, :, 1:] + grids[:, :, :-1]) / 2, axis=2)],
                                    axis=2)
        row_totals = along_rows[:, :, -1]
        down = np.concatenate([np.zeros((len(grids), 1)),
                               np.cumsum((row_totals[:, 1:] + row_totals[:, :-1]) / 2, axis=1)],
                              axis=1)
        scale = 1.0 / down[:, -1]
        self.grids = self.grids * scale[:, None]
        self.conditional = (along_rows * scale[:, None, None]).reshape(len(grids), -1)
        self.marginal = down * scale[:, None]

    def invert(self, pos: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        """The uniform point (n, 2) that the warp sends to each point ``pos`` (n, 2)."""
        corners = self.slice_weights(params, len(pos))
        col, row, fx, fy = self.cell(pos)
        lt, rt, lb, rb = self.corners_of_cell(col, row, corners)
        left, right = (1 - fy) * lt + fy * lb, (1 - fy) * rt + fy * rb  # density along x at y
        top = row * self.cols

        def conditional(at: np.ndarray) -> np.ndarray:
            """The conditional integral up to column node ``at``, at the point's y."""
            return ((1 - fy) * self.gather(self.conditional, corners, top + at)
                    + fy * self.gather(self.conditional, corners, top + self.cols + at))

        across = conditional(col) + fx * (left + fx * (right - left) / 2)
        x = across / conditional(np.full_like(col, self.cols - 1))
        r_top = self.gather(self.conditional, corners, top + self.cols - 1)
        r_bottom = self.gather(self.conditional, corners, top + 2 * self.cols - 1)
        y = self.gather(self.marginal, corners, row) + fy * (r_top + fy * (r_bottom - r_top) / 2)
        return np.stack([x, y], axis=-1)
