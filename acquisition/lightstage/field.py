"""Reflectance fields: one linear EXR per light, calibrated, with the light in the metadata.

Each OLAT sample frame k becomes ``light-KKK.exr`` (float32 RGB, same superpixel grid as the
frames) holding the pixel's *reflectance function* for that light,

    R_k(p) = P_k(p) / C_k · r_k(p)²        [sr⁻¹]

the radiance the pixel sees per unit irradiance the light delivers at normal incidence
(f · cos θi for a sample pixel), with P_k the dark-subtracted frame (DN/s), C_k the LED's
white-target calibration (:func:`acquisition.lightstage.reduce.led_calibration`) and r_k(p)
the light's distance from the surface point the pixel sees (the dome radius off the sample).
Dividing by C_k removes each LED's own intensity error; r_k² removes the finite dome
distance, so the field relights like distant lights. Pixels that clipped are NaN.

Attributes (OpenImageIO, typed): ``gonio:light_index`` (int), ``gonio:light_direction``
(float[3], sample frame), ``gonio:solid_angle_sr`` (float), ``gonio:calibration``
(float[3], C_k), ``gonio:relative_intensity`` (float[3], C_k / mean), ``gonio:camera_direction``
(float[3]), ``gonio:light_distance_m``, ``gonio:units``, ``gonio:session``, ``gonio:step``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.lightstage.reduce import _done, dark_rate, led_calibration, light_of, load_frame
from acquisition.reduction.imaging import PinholeCamera, camera_intrinsics, intersect
from acquisition.session.folder import SessionFolder
from acquisition.session.steps import POSE
from calibration.exr import exr_has, read_exr, write_exr
from drivers.errors import SessionError
from drivers.storage import check_folder, check_output, ensure_folder

UNITS = "sr^-1: radiance per unit normal irradiance from the light"
FILE_FORMAT = "light-{index:03d}.exr"
WHAT = "reflectance-field image"
is_field_image = exr_has("gonio:light_index")
"""True for a reflectance-field image gonio wrote (it may be replaced)."""


@dataclass(frozen=True)
class ReflectanceField:
    """A captured reflectance field.

    Attributes
    ----------
    images:
        (N, h, w, 3) float32 reflectance functions R_k (sr⁻¹).
    directions:
        (N, 3) unit light directions, sample frame.
    solid_angles_sr:
        (N,) solid angle each light stands for (sr).
    indices:
        (N,) dome index of each light.
    """

    images: np.ndarray
    directions: np.ndarray
    solid_angles_sr: np.ndarray
    indices: np.ndarray

    def __len__(self) -> int:
        return len(self.indices)


def _distance_sq(folder: SessionFolder, light_dir: np.ndarray, camera_dir: np.ndarray,
                 shape: tuple[int, int]) -> np.ndarray:
    """r_k(p)² (h, w), m²: light to the surface point each pixel sees (dome radius² off it)."""
    rig = folder.rig()
    camera = PinholeCamera.looking_at_origin(camera_intrinsics(rig, shape), shape, camera_dir,
                                             rig.camera_distance_m)
    hits = intersect(rig.sample, camera.position, camera.ray_directions())
    r2 = np.full(shape, rig.light_distance_m**2)
    to_light = light_dir * rig.light_distance_m - hits.points
    r2[hits.hit] = np.einsum("ij,ij->i", to_light, to_light)
    return r2


def write_field(session_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Write the session's OLAT sample frames as a calibrated reflectance field; returns the
    EXR paths in dome order."""
    folder = SessionFolder(session_dir)
    rig = folder.rig()
    inputs = (folder.path,)
    out = check_folder(out_dir, what="reflectance field", inputs=inputs)
    cal = led_calibration(folder.path)
    records = _done(folder)
    olat = [r for r in records if r.kind == POSE and light_of(r) is not None]
    if not olat:
        raise SessionError(f"{folder.path} has no OLAT sample frame: capture with --sequence olat")
    ensure_folder(out, what="reflectance field", inputs=inputs)
    for rec in olat:  # refuse before writing any
        check_output(out / FILE_FORMAT.format(index=light_of(rec)), what=WHAT,
                     ours=is_field_image, inputs=inputs)
    dark = dark_rate(folder, records)
    from acquisition.config.stage import stage_config

    stage = stage_config(rig)
    relative = cal.relative
    paths = []
    for rec in olat:
        k = light_of(rec)
        assert k is not None
        image = load_frame(folder, rec, dark)
        r2 = _distance_sq(folder, stage.directions[k], stage.camera_dir, image.valid.shape)
        field = image.rgb / cal.require(k, str(folder.path)) * r2[..., None]
        path = out / FILE_FORMAT.format(index=k)
        write_exr(path, field, {
            "gonio:light_index": k,
            "gonio:light_direction": stage.directions[k],
            "gonio:solid_angle_sr": float(stage.solid_angles_sr[k]),
            "gonio:calibration": cal.scale[k],
            "gonio:relative_intensity": relative[k],
            "gonio:camera_direction": stage.camera_dir,
            "gonio:light_distance_m": float(rig.light_distance_m),
            "gonio:units": UNITS,
            "gonio:session": str(folder.path.resolve()),
            "gonio:step": rec.step,
        }, what=WHAT, ours=is_field_image, inputs=inputs)
        paths.append(path)
    return sorted(paths)


def load_field(field_dir: str | Path) -> ReflectanceField:
    """Read a reflectance field written by :func:`write_field` (every ``light-*.exr``)."""
    paths = sorted(Path(field_dir).glob("light-*.exr"))
    if not paths:
        raise SessionError(f"{field_dir} holds no light-*.exr: give the folder "
                           "`gonio lightstage field` wrote")
    images, dirs, omegas, idx = [], [], [], []
    for p in paths:
        img, attrs = read_exr(p)
        try:
            dirs.append(np.asarray(attrs["gonio:light_direction"], dtype=float))
            omegas.append(float(attrs["gonio:solid_angle_sr"]))  # type: ignore[arg-type]
            idx.append(int(attrs["gonio:light_index"]))  # type: ignore[call-overload]
        except KeyError as exc:
            raise SessionError(f"{p} lacks the {exc.args[0]} attribute: it is not a gonio "
                               "reflectance-field image") from None
        images.append(img[..., :3])
    return ReflectanceField(np.stack(images), np.array(dirs), np.array(omegas), np.array(idx))
