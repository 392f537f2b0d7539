"""A calibration bundle: one folder holding a camera's calibration, with provenance.

Layout::

    bundle.json               scalars: format, noise models, white reference, geometry (the
                              rig's zero offsets and sample tilt), and for every image its
                              file, shape and provenance (who, when, from what)
    dark-t0.01-iso100.exr     master dark per (exposure s, ISO), DN, black level included
    flat.exr                  flat field, mean 1 per colour
    bad-pixels.exr            1 where a pixel must not be used

Images are single-channel float32 OpenEXR files written through OpenImageIO (float32 holds
every 16-bit DN exactly); each EXR also carries its own ``gonio:*`` attributes. Every file goes
through :func:`drivers.storage.atomic_output` (verified, then renamed), so a bundle never holds
half an image.

Use :meth:`CalibrationBundle.open` (existing folder) or :meth:`CalibrationBundle.create`.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from calibration import exr
from calibration.linearize import LinearImage, NoiseModel, linearize
from calibration.raw import RawFrame
from drivers.errors import CalibrationError, ConfigError
from drivers.storage import check_folder, ensure_folder, write_text

BUNDLE_FORMAT = "gonio-calibration-bundle"
BUNDLE_VERSION = 1
SCALARS_FILE = "bundle.json"
FLAT_FILE = "flat.exr"
BAD_PIXELS_FILE = "bad-pixels.exr"


def dark_name(exposure_s: float, iso: float) -> str:
    """File name of the master dark for ``exposure_s`` (s) and ``iso``."""
    return f"dark-t{exposure_s:.6g}-iso{iso:g}.exr"


def provenance(**extra: Any) -> dict[str, Any]:
    """When and where something was made, plus ``extra`` (source frames, rig, counts)."""
    return {
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "host": platform.node(),
        **extra,
    }


IMAGE_KIND = "gonio:kind"
"""Attribute every bundle image carries (dark, flat, bad_pixels): how a bundle tells its own
images from other files it must not overwrite."""


def _is_bundle_json(path: Path) -> bool:
    try:
        return json.loads(path.read_text()).get("format") == BUNDLE_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def _is_bundle_json_or_raise(path: Path) -> None:
    if not _is_bundle_json(path):
        raise ValueError(f"{path} does not parse as a {BUNDLE_FORMAT} file")


def write_exr(path: Path, image: np.ndarray, attributes: Mapping[str, Any] | None = None) -> None:
    """Write a 2-D (or H×W×C) array as float32 OpenEXR with ``gonio:*`` attributes, atomically
    (a previous bundle image may be replaced, any other file is refused)."""
    attrs = {f"gonio:{k}": (int(v) if isinstance(v, bool) else v)
             for k, v in (attributes or {}).items()}
    exr.write_exr(path, image, attrs, what="calibration image", compression="zip",
                  ours=exr.exr_has(IMAGE_KIND))


def read_exr(path: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """Read an EXR: (H×W float32 for one channel, else H×W×C) and its ``gonio:*`` attributes."""
    try:
        arr, attrs = exr.read_exr(path)
    except ConfigError:
        raise CalibrationError(f"cannot read calibration image {path} (unreadable or truncated); "
                               "re-run gonio calibrate") from None
    ours = {k.split(":", 1)[1]: v for k, v in attrs.items() if k.startswith("gonio:")}
    return (arr[:, :, 0] if arr.shape[2] == 1 else arr), ours


class CalibrationBundle:
    """A calibration folder (see module docstring). Changes are saved at once."""

    def __init__(self, path: Path, scalars: dict[str, Any]) -> None:
        self.path = path
        self._scalars = scalars
        self._cache: dict[str, np.ndarray | None] = {}

    # -- opening ---------------------------------------------------------------------------
    @classmethod
    def create(
        cls, path: str | os.PathLike[str], camera: Mapping[str, Any] | None = None
    ) -> CalibrationBundle:
        """Open ``path`` if it is a bundle, else make a new empty one there."""
        path = check_folder(path, what="calibration bundle")  # not a session's own copy
        if (path / SCALARS_FILE).exists():
            return cls.open(path)
        ensure_folder(path, what="calibration bundle")
        bundle = cls(path, {"format": BUNDLE_FORMAT, "version": BUNDLE_VERSION,
                            "camera": dict(camera or {}), "darks": {}, "noise": {}})
        bundle._save()
        return bundle

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> CalibrationBundle:
        """Open an existing bundle folder."""
        path = Path(path)
        file = path / SCALARS_FILE
        try:
            scalars = json.loads(file.read_text())
        except (FileNotFoundError, NotADirectoryError):
            raise CalibrationError(
                f"{path} is not a calibration bundle (no {SCALARS_FILE}): give the folder "
                "`gonio calibrate dark|flat|noise|white --out FOLDER` wrote"
            ) from None
        except json.JSONDecodeError as exc:
            raise CalibrationError(f"{file}: not valid JSON ({exc}); re-run gonio calibrate") from None
        if scalars.get("format") != BUNDLE_FORMAT or scalars.get("version") != BUNDLE_VERSION:
            raise CalibrationError(
                f"{file}: not a {BUNDLE_FORMAT} v{BUNDLE_VERSION} file; re-run gonio calibrate"
            )
        return cls(path, scalars)

    def _save(self) -> None:
        self._cache.clear()
        write_text(self.path / SCALARS_FILE, json.dumps(self._scalars, indent=2, sort_keys=True)
                   + "\n", what="calibration bundle file", ours=_is_bundle_json,
                   verify=_is_bundle_json_or_raise)

    @property
    def scalars(self) -> dict[str, Any]:
        """A copy of everything in ``bundle.json``."""
        return json.loads(json.dumps(self._scalars))

    # -- darks -----------------------------------------------------------------------------
    def add_dark(self, dark: np.ndarray, exposure_s: float, iso: float, prov: Mapping[str, Any]) -> Path:
        """Store a master dark (H×W, DN) for (exposure s, ISO)."""
        name = dark_name(exposure_s, iso)
        write_exr(self.path / name, dark, {"kind": "dark", "exposure_s": float(exposure_s),
                                           "iso": float(iso)})
        self._scalars["darks"][name] = {"exposure_s": float(exposure_s), "iso": float(iso),
                                        "shape": list(dark.shape), "provenance": dict(prov)}
        self._save()
        return self.path / name

    def dark_for(self, exposure_s: float, iso: float, *, rel_tol: float = 1e-6) -> np.ndarray | None:
        """The master dark taken at this exposure and ISO, or None."""
        for name, entry in self._scalars["darks"].items():
            if entry["iso"] == float(iso) and math.isclose(entry["exposure_s"], exposure_s,
                                                           rel_tol=rel_tol):
                return read_exr(self.path / name)[0]
        return None

    # -- flat, bad pixels --------------------------------------------------------------------
    def set_flat(self, flat: np.ndarray, prov: Mapping[str, Any]) -> None:
        """Store the flat field (H×W, mean 1 per colour)."""
        write_exr(self.path / FLAT_FILE, flat, {"kind": "flat"})
        self._scalars["flat"] = {"file": FLAT_FILE, "shape": list(flat.shape), "provenance": dict(prov)}
        self._save()

    @property
    def flat(self) -> np.ndarray | None:
        """The flat field, or None."""
        return read_exr(self.path / FLAT_FILE)[0] if "flat" in self._scalars else None

    def set_bad_pixels(self, bad: np.ndarray, prov: Mapping[str, Any]) -> None:
        """Store the bad-pixel map (H×W bool)."""
        write_exr(self.path / BAD_PIXELS_FILE, bad.astype(np.float32), {"kind": "bad_pixels"})
        self._scalars["bad_pixels"] = {"file": BAD_PIXELS_FILE, "count": int(np.count_nonzero(bad)),
                                       "shape": list(bad.shape), "provenance": dict(prov)}
        self._save()

    @property
    def bad_pixels(self) -> np.ndarray | None:
        """The bad-pixel map (H×W bool), or None."""
        if "bad_pixels" not in self._scalars:
            return None
        return read_exr(self.path / BAD_PIXELS_FILE)[0] > 0.5

    # -- noise -----------------------------------------------------------------------------
    def set_noise(self, model: NoiseModel, prov: Mapping[str, Any]) -> None:
        """Store a noise model for its ISO (``model.iso`` must be set)."""
        if model.iso is None:
            raise CalibrationError("a bundle stores noise models per ISO: set NoiseModel.iso")
        gain, read = model.per_colour()
        self._scalars["noise"][f"{model.iso:g}"] = {
            "iso": float(model.iso), "gain_e_per_dn": gain.tolist(),
            "read_noise_dn": read.tolist(), "provenance": dict(prov),
        }
        self._save()

    def noise_for(self, iso: float) -> NoiseModel | None:
        """The noise model measured at ``iso``, or None."""
        entry = self._scalars["noise"].get(f"{iso:g}")
        if entry is None:
            return None
        return NoiseModel(tuple(entry["gain_e_per_dn"]), tuple(entry["read_noise_dn"]), entry["iso"])

    # -- applying it ------------------------------------------------------------------------
    def linearize(self, frame: RawFrame, *, require_noise: bool = False, **kwargs: Any) -> LinearImage:
        """:func:`~calibration.linearize.linearize` with this bundle's dark (for the frame's
        exposure and ISO, if measured), flat, bad pixels and noise model (for its ISO).

        Raises
        ------
        CalibrationError
            ``require_noise`` and no noise model at the frame's ISO.
        """
        if "flat" not in self._cache:
            self._cache["flat"] = self.flat
            self._cache["bad"] = self.bad_pixels
        exposure = kwargs.get("exposure_s") or frame.exposure_s
        dark = None
        if exposure is not None and frame.iso is not None:
            key = f"dark:{exposure:.9g}:{frame.iso:g}"
            if key not in self._cache:
                self._cache[key] = self.dark_for(exposure, frame.iso)
            dark = self._cache[key]
        noise = self.noise_for(frame.iso) if frame.iso is not None else None
        if noise is None and require_noise:
            raise CalibrationError(
                f"{self.path}: no noise model for ISO {frame.iso} ({frame.path}); run "
                f"gonio calibrate noise --iso {frame.iso}"
            )
        return linearize(frame, dark=dark, flat=self._cache["flat"], bad_pixels=self._cache["bad"],
                         noise=noise, **kwargs)

    # -- white reference ----------------------------------------------------------------------
    def set_white(self, white: Mapping[str, Any], prov: Mapping[str, Any]) -> None:
        """Store the white-reference measurement (see :mod:`calibration.white`)."""
        self._scalars["white"] = {**dict(white), "provenance": dict(prov)}
        self._save()

    @property
    def white(self) -> dict[str, Any] | None:
        """The stored white-reference measurement, or None."""
        w = self._scalars.get("white")
        return None if w is None else dict(w)

    # -- geometry ---------------------------------------------------------------------------
    def set_geometry(self, geometry: Mapping[str, Any], prov: Mapping[str, Any]) -> None:
        """Store the rig's geometric calibration (zero offsets, sample tilt, their covariance:
        ``acquisition.geometry.alignment.Alignment.to_dict``, and the fit's figures)."""
        self._scalars["geometry"] = {**dict(geometry), "provenance": dict(prov)}
        self._save()

    @property
    def geometry(self) -> dict[str, Any] | None:
        """The stored geometric calibration, or None."""
        g = self._scalars.get("geometry")
        return None if g is None else json.loads(json.dumps(g))
