"""Arithmetic of the reduction path in a fixed order, the same bits on every CPU.

numpy dispatches some operations at run time on the CPU's SIMD features, and BLAS picks its
kernels by CPU: ``einsum`` and ``@`` (OpenBLAS ``dgemv``/``ddot``, fused multiply-adds on
Haswell and later, not on older cores) sum in orders, and round in places, that change with
the machine. The reduction's per-sample values instead go through elementwise IEEE ``+ − × /``
and √ only (correctly rounded everywhere, never fused across separate numpy calls), in the
order written here; the compiled kernels (:mod:`acquisition.reduction.imaging_kernels`,
:mod:`acquisition.reduction.sample_kernels`) do the same operations in the same order.
tests/test_cpu_dispatch.py reduces a session under reduced CPU features and another OpenBLAS
core and compares the tables bit for bit.
"""

from __future__ import annotations

import numpy as np


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (…, 3) arrays: (a₀b₀ + a₁b₁) + a₂b₂."""
    return (a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]) + a[..., 2] * b[..., 2]


def norm3(v: np.ndarray) -> np.ndarray:
    """Row-wise Euclidean norm of a (…, 3) array: √((v₀² + v₁²) + v₂²)."""
    return np.sqrt(dot3(v, v))


def weighted_variance(weights: np.ndarray, variances: np.ndarray) -> np.ndarray:
    """Σₖ wₖ²·vₖ over the rows of ``variances`` (K, C), each product rounded, then added in
    row order (what ``(w**2) @ variances`` means, without BLAS's fused multiply-adds)."""
    w2 = np.asarray(weights, dtype=np.float64) ** 2
    v = np.asarray(variances, dtype=np.float64)
    total = np.zeros(v.shape[1:])
    for k in range(v.shape[0]):
        total = total + w2[k] * v[k]
    return total
