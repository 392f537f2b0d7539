"""BRDF tables: streaming binning into isotropic (θi, θr, Δφ) and MERL half/difference grids
with exact (fixed-point) per-bin sums, binning kernels, partial tables that merge in any
grouping, HDF5 files.

May import: ``acquisition.geometry``, ``drivers.numba_cache``, ``drivers.errors``,
``drivers.storage``.
"""

from acquisition.tables.accumulator import BinAccumulator
from acquisition.tables.angles import fold_delta_phi, wrap_delta_phi
from acquisition.tables.isotropic import IsotropicTable
from acquisition.tables.merl_table import MerlTable

__all__ = ["BinAccumulator", "IsotropicTable", "MerlTable", "fold_delta_phi", "wrap_delta_phi"]
