"""The geometric calibration a session applies: the ``geometry`` section of its calibration
bundle (``gonio calibrate geometry``) as an :class:`~acquisition.geometry.alignment.Alignment`.

A capture given ``--calibration BUNDLE`` plans with it (joint targets that realise each pose on
the real rig) and copies the bundle into the session, so a resume plans the same way; a
reduction applies the bundle it is given, else the session's copy.
"""

from __future__ import annotations

from pathlib import Path

from acquisition.config.rig import RigConfig
from acquisition.geometry.alignment import Alignment
from calibration.bundle import SCALARS_FILE, CalibrationBundle
from drivers.errors import CalibrationError


def bundle_at(path: str | Path | None) -> CalibrationBundle | None:
    """The calibration bundle at ``path`` (a folder holding ``bundle.json``), else None."""
    if path is None or not (Path(path) / SCALARS_FILE).is_file():
        return None
    return CalibrationBundle.open(path)


def alignment_of(bundle: CalibrationBundle | None, rig: RigConfig) -> Alignment | None:
    """The bundle's geometric calibration for ``rig``, or None when it has none.

    Raises
    ------
    CalibrationError
        The section is malformed, or names an axis the rig does not have (a bundle of
        another rig).
    """
    section = None if bundle is None else bundle.geometry
    if not section:
        return None
    try:
        alignment = Alignment.from_dict(section)
    except (KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{bundle.path}: the geometry section is malformed ({exc}): "  # type: ignore[union-attr]
                               "run gonio calibrate geometry again") from None
    stray = [a for a in alignment.zero_offset_deg if a not in rig.axes]
    if stray:
        raise CalibrationError(f"{bundle.path}: the geometric calibration names axis "  # type: ignore[union-attr]
                               f"'{stray[0]}', which {rig.path} does not have: use the bundle "
                               "made on this rig")
    return alignment
