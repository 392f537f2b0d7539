"""MERL BRDF database files: read, write, evaluate, and use as a simulated material.

File layout (what the MERL reference reader ``BRDFRead.cpp`` reads), 34,992,012 bytes:

* header: three little-endian int32, 90, 90, 180 (θh, θd, φd bins; the reader checks only
  their product, 1,458,000);
* three planes R, G, B of 1,458,000 little-endian float64 each, C order over
  (θh, θd, φd) with φd fastest: flat index ``(ih·90 + id)·180 + ip``;
* stored value = BRDF / scale, so BRDF (sr⁻¹) = stored value × scale with scales
  R 1/1500, G 1.15/1500, B 1.66/1500;
* negative values mark unmeasured bins (the reference prints "Below horizon.").

The simulated camera's ``merl:PATH`` material does not use this module: it reads and evaluates
the file with the simulator's own code (:mod:`simulators.measured.merl`), so that a bug here or in
:mod:`acquisition.geometry.halfdiff` shows in a capture-and-reduce round trip.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from acquisition.geometry.halfdiff import (
    MERL_BINS,
    MERL_SHAPE,
    halfdiff_rad_from_vectors,
    halfdiff_rad_reference,
    merl_flat_index_rad,
)
from acquisition.tables.merl_table import MerlTable
from drivers.errors import ConfigError
from drivers.storage import atomic_output

MERL_SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
"""BRDF (sr⁻¹) = stored value × scale, per channel R, G, B."""
MERL_HEADER = (90, 90, 180)
HEADER_BYTES = 12
MERL_FILE_BYTES = HEADER_BYTES + 3 * MERL_BINS * 8
"""Exact size of a MERL file: 34,992,012 bytes."""
WHAT = "MERL file"
UNMEASURED = -1.0
"""Stored value written for unmeasured bins (any negative value marks one)."""


class MerlBRDF:
    """A BRDF on the MERL grid, as stored in a MERL file.

    Parameters
    ----------
    stored
        (3, 90, 90, 180) float64 stored values (BRDF / scale; negative = unmeasured).
    header
        The file's three int32 dimensions, kept so a rewrite reproduces the file exactly.
    path
        Where it was read from, if anywhere.
    """

    def __init__(
        self,
        stored: np.ndarray,
        header: tuple[int, int, int] = MERL_HEADER,
        path: str | os.PathLike[str] | None = None,
    ) -> None:
        stored = np.asarray(stored, dtype=np.float64)
        if stored.size != 3 * MERL_BINS:
            raise ConfigError(f"MERL data need 3 x {MERL_BINS} values, got {stored.size}")
        self.stored = stored.reshape(3, *MERL_SHAPE)
        self.header = tuple(int(h) for h in header)
        self.path = None if path is None else Path(path)
        # Per-bin BRDF with RGB last, computed as the reference does (stored × scale).
        self._flat = np.ascontiguousarray(self.stored.reshape(3, MERL_BINS).T) * MERL_SCALES

    @property
    def values(self) -> np.ndarray:
        """BRDF per bin, float64 [90, 90, 180, 3] in sr⁻¹ (negative where unmeasured)."""
        return self._flat.reshape(*MERL_SHAPE, 3).copy()

    @property
    def measured(self) -> np.ndarray:
        """Bins whose three channels are all ≥ 0, bool [90, 90, 180]."""
        return (self.stored >= 0).all(axis=0)

    def lookup_rad(
        self,
        theta_in: np.ndarray | float,
        phi_in: np.ndarray | float,
        theta_out: np.ndarray | float,
        phi_out: np.ndarray | float,
    ) -> np.ndarray:
        """The reference lookup for spherical angles in radians: (…, 3) in sr⁻¹.

        Nearest bin, no interpolation, indices clamped, negative values returned as stored
        (× scale) for unmeasured bins; exactly the reference reader's arithmetic.
        """
        th, td, pd = halfdiff_rad_reference(theta_in, phi_in, theta_out, phi_out)
        return self._flat[merl_flat_index_rad(th, td, pd, clamp=True)]

    def __call__(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
    ) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ at (θi, θr, Δφ) in degrees, as the reference lookup returns it.

        The light is at azimuth 0 and the view at azimuth Δφ. Unmeasured bins give negative
        values, as in the reference; below-horizon angles are not special-cased.
        """
        return self.lookup_rad(
            np.radians(theta_i_deg), 0.0, np.radians(theta_r_deg), np.radians(delta_phi_deg)
        )

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ for unit light ``wi`` and view ``wo`` vectors (…, 3), normal +z.

        Same nearest-bin lookup as :meth:`__call__`, from vectors directly (agrees with the
        reference up to float rounding at bin boundaries).
        """
        th, td, pd = halfdiff_rad_from_vectors(wi, wo)
        return self._flat[merl_flat_index_rad(th, td, pd, clamp=True)]


# ---------------------------------------------------------------------------- file I/O
def is_merl_file(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` has a MERL file's exact size and header (one gonio may replace)."""
    try:
        if os.path.getsize(path) != MERL_FILE_BYTES:
            return False
        with open(path, "rb") as fh:
            header = np.frombuffer(fh.read(HEADER_BYTES), dtype="<i4")
    except OSError:
        return False
    return len(header) == 3 and int(np.prod(header, dtype=np.int64)) == MERL_BINS


def _verify_merl(tmp: Path) -> None:
    if not is_merl_file(tmp):
        raise ValueError(f"{os.path.getsize(tmp)} bytes, expected a {MERL_FILE_BYTES}-byte MERL file")


def read_merl(path: str | os.PathLike[str]) -> MerlBRDF:
    """Read a MERL ``.binary`` file; raises :class:`ConfigError` if it is missing or malformed."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"MERL file {path} does not exist: check the path") from None
    except OSError as exc:
        raise ConfigError(f"MERL file {path} cannot be read: {exc.strerror or exc}") from None
    if len(raw) < HEADER_BYTES:
        raise ConfigError(f"MERL file {path} is {len(raw)} bytes, too short for a header")
    header = tuple(int(v) for v in np.frombuffer(raw, dtype="<i4", count=3))
    if np.prod(header, dtype=np.int64) != MERL_BINS:
        raise ConfigError(
            f"MERL file {path}: header {header} does not hold 90 x 90 x 180 bins; "
            "not a MERL BRDF file"
        )
    if len(raw) != MERL_FILE_BYTES:
        raise ConfigError(
            f"MERL file {path} is {len(raw)} bytes, expected {MERL_FILE_BYTES}; "
            "the file is truncated or not a MERL BRDF"
        )
    stored = np.frombuffer(raw, dtype="<f8", offset=HEADER_BYTES).astype(np.float64)
    return MerlBRDF(stored, header, path)  # type: ignore[arg-type]


def merl_stored_values(
    source: MerlBRDF | MerlTable | np.ndarray, unmeasured: float = UNMEASURED
) -> np.ndarray:
    """(3, 90, 90, 180) stored values (BRDF / scale) for what :func:`write_merl` accepts."""
    if unmeasured >= 0 or not np.isfinite(unmeasured):
        raise ValueError(f"unmeasured marker must be a finite negative number, got {unmeasured}")
    if isinstance(source, MerlBRDF):
        return source.stored
    if isinstance(source, MerlTable):
        brdf = source.mean
    else:
        brdf = np.asarray(source, dtype=np.float64)
        if brdf.shape == (3, *MERL_SHAPE):
            brdf = np.moveaxis(brdf, 0, -1)
        elif brdf.shape != (*MERL_SHAPE, 3):
            raise ValueError(
                f"MERL data must be shaped (90, 90, 180, 3) or (3, 90, 90, 180), got {brdf.shape}"
            )
    stored = np.moveaxis(brdf / MERL_SCALES, -1, 0)
    return np.where(np.isnan(stored), unmeasured, stored)


def write_merl(
    path: str | os.PathLike[str],
    source: MerlBRDF | MerlTable | np.ndarray,
    *,
    unmeasured: float = UNMEASURED,
    inputs: Iterable[str | os.PathLike[str]] = (),
) -> None:
    """Write a MERL file that the MERL reference reader loads, through
    :func:`drivers.storage.atomic_output` (an existing MERL file may be replaced, ``inputs`` and
    any other file are refused).

    Parameters
    ----------
    path
        Output file (usually ``*.binary``).
    source
        A :class:`MerlBRDF` (written back exactly as read: ``write_merl(p, read_merl(src))``
        reproduces ``src`` byte for byte), a :class:`~acquisition.tables.MerlTable` (its mean;
        empty bins unmeasured), or an array of BRDF values in sr⁻¹ shaped (90, 90, 180, 3) or
        (3, 90, 90, 180) where NaN marks unmeasured bins.
    unmeasured
        Negative stored value written for unmeasured bins.
    """
    stored = merl_stored_values(source, unmeasured)
    header = source.header if isinstance(source, MerlBRDF) else MERL_HEADER
    with atomic_output(path, what=WHAT, verify=_verify_merl, ours=is_merl_file,
                       inputs=inputs) as tmp, open(tmp, "wb") as fh:
        fh.write(np.asarray(header, dtype="<i4").tobytes())
        fh.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
