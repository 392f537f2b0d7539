"""Making a calibration bundle on a rig: ``gonio calibrate dark|flat|noise|white``.

Each kind captures its frames through the rig's devices (:func:`acquisition.devices.rig.open_devices`)
at the white-reference pose and stores its result in a :class:`calibration.bundle.CalibrationBundle`:

``dark``   ≥ 8 lens-capped frames per (exposure, ISO) → median master dark, bad-pixel map;
``flat``   16 frames of a uniform target at about half the well (and their master dark) →
           flat field, bad-pixel map from dark and flat;
``noise``  pairs of uniform-target frames over a geometric exposure series plus a dark pair →
           photon transfer → conversion gain and read noise per colour at the ISO;
``white``  the white reference at the rig's reference geometry, linearized with whatever the
           bundle holds → per-colour signal, reflectance, θi and light distance.

On a simulated rig the sample holder presents the simulator's calibration targets
(:class:`acquisition.simworld.scene.SampleHolder`): ``"cap"`` (the lens cap, a black frame) and
``"uniform"`` (the white reference's radiance over the whole frame), seen by the rig's own
camera on its simulated clock (with the rig's light drift, if it states one).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.config.rig import RigConfig, load_rig
from acquisition.devices.rig import RigDevices, open_devices
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from acquisition.simworld.scene import TARGETS, SampleHolder, white_material
from calibration.bundle import CalibrationBundle, provenance
from calibration.dark import MIN_DARK_FRAMES, bad_pixel_map, master_dark
from calibration.flat import flat_field
from calibration.linearize import linearize
from calibration.noise import photon_transfer
from calibration.raw import RawFrame, load_raw
from calibration.white import measure_white
from drivers.errors import CalibrationError, ConfigError

KINDS = ("dark", "flat", "noise", "white")
FLAT_FRAMES = 16
WHITE_FRAMES = 4
FLAT_FILL = 0.4
"""Target fraction of (white − black) for flat and white frames."""

Progress = Callable[[int, int], None]


@dataclass
class CalibrationRun:
    """What one ``gonio calibrate`` produced."""

    kind: str
    bundle: Path
    frames: int
    summary: dict[str, Any] = field(default_factory=dict)


class _Frames:
    """Takes frames of one target into a temporary folder through the rig's camera.

    ``seed`` offsets the frames' noise seeds, so each series has its own noise.
    """

    def __init__(self, dev: RigDevices, target: str, folder: Path, iso: int,
                 progress: Progress | None, total: int, seed: int = 0) -> None:
        if not isinstance(dev.holder, SampleHolder):  # pragma: no cover - hardware
            raise ConfigError(f"{dev.rig.path}: calibration on real cameras is not wired yet")
        self.dev, self.target, self.folder, self.iso = dev, target, folder, iso
        self.progress, self.total, self.count = progress, total, 0
        self.seed = seed

    def take(self, exposure_s: float, tag: str) -> RawFrame:
        path = self.folder / f"{tag}-{self.target}-{self.seed}-{self.count:04d}.dng"
        self.dev.present(self.target)
        series = self.seed * 1_000_003 + TARGETS.index(self.target) * 100_003
        self.dev.capture(path, exposure_s, self.iso, series + self.count)
        self.count += 1
        if self.progress:
            self.progress(min(self.count, self.total), self.total)
        return load_raw(path)


def _fill(frame: RawFrame) -> float:
    """Mean level of the brightest colour as a fraction of (white − black)."""
    span = frame.white_per_position - frame.black_per_position
    level = frame.mosaic.reshape(frame.height // 2, 2, frame.width // 2, 2).mean(axis=(0, 2))
    return float(np.max((level - frame.black_per_position) / span))


def _expose_for_fill(take: Callable[[float], RawFrame], start_s: float, target: float,
                     region: Callable[[RawFrame], RawFrame] = lambda f: f) -> float:
    """Exposure (s) giving a mean fill of about ``target``, in ≤ 6 test frames."""
    t = start_s
    for _ in range(6):
        fill = _fill(region(take(t)))
        if fill > 0.97:
            t /= 8
            continue
        if fill <= 0:
            t *= 8
            continue
        t_new = t * target / fill
        if abs(t_new / t - 1) < 0.1:
            return t_new
        t = t_new
    return t


def calibrate(
    kind: str,
    rig_path: str | Path,
    bundle_path: str | Path,
    *,
    frames: int | None = None,
    exposure_s: float | None = None,
    iso: int | None = None,
    seed: int = 0,
    progress: Progress | None = None,
) -> CalibrationRun:
    """Capture one kind of calibration on a rig and store it in the bundle at ``bundle_path``.

    Parameters
    ----------
    kind:
        ``"dark"``, ``"flat"``, ``"noise"`` or ``"white"``.
    frames:
        Frames per master dark / flat / white measurement (defaults 8 / 16 / 4).
    exposure_s, iso:
        Override the rig's camera exposure (dark, white) and ISO.
    """
    if kind not in KINDS:
        raise ConfigError(f"unknown calibration kind {kind!r}; choose one of {', '.join(KINDS)}")
    rig = load_rig(rig_path)
    iso = int(iso or rig.camera.iso)
    exposure = float(exposure_s or rig.camera.exposure_s)
    planner = Planner(rig)
    wr = rig.white_reference
    with open_devices(rig, planner, material=white_material(rig), seed=seed) as dev, \
            tempfile.TemporaryDirectory(prefix=f"gonio-{kind}-") as tmp:
        joints = dev.move_to(dict(planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi))))
        bundle = CalibrationBundle.create(bundle_path, camera=dev.camera.describe())
        folder = Path(tmp)
        prov = {"rig": str(rig.path), "rig_name": rig.name, "seed": seed}
        runner = {"dark": _dark, "flat": _flat, "noise": _noise, "white": _white}[kind]
        return runner(dev, planner, joints, bundle, folder, prov, exposure=exposure, iso=iso,
                      frames=frames, seed=seed, progress=progress, rig=rig)


def _take_dark(dev: RigDevices, folder: Path, exposure: float, iso: int, n: int, seed: int,
               progress: Progress | None) -> np.ndarray:
    cam = _Frames(dev, "cap", folder, iso, progress, n, seed)
    return master_dark([cam.take(exposure, f"dark-{exposure:g}") for _ in range(n)])


def _dark(dev, planner, joints, bundle, folder, prov, *, exposure, iso, frames, seed, progress,
          rig) -> CalibrationRun:
    n = frames or MIN_DARK_FRAMES
    dark = _take_dark(dev, folder, exposure, iso, n, seed, progress)
    bundle.add_dark(dark, exposure, iso, provenance(frames=n, **prov))
    flat = bundle.flat
    bad = bad_pixel_map("RGGB", dark=dark, flat=flat)
    bundle.set_bad_pixels(bad, provenance(dark_exposure_s=exposure, iso=iso, with_flat=flat is not None,
                                          **prov))
    return CalibrationRun("dark", bundle.path, n, {"exposure_s": exposure, "iso": iso,
                                                   "mean_dn": float(dark.mean()),
                                                   "bad_pixels": int(bad.sum())})


def _flat(dev, planner, joints, bundle, folder, prov, *, exposure, iso, frames, seed, progress,
          rig) -> CalibrationRun:
    n = frames or FLAT_FRAMES
    cam = _Frames(dev, "uniform", folder, iso, progress, n + MIN_DARK_FRAMES, seed)
    t = _expose_for_fill(lambda e: cam.take(e, "test"), exposure, FLAT_FILL)
    flats = [cam.take(t, "flat") for _ in range(n)]
    dark = bundle.dark_for(t, iso)
    if dark is None:
        dark = _take_dark(dev, folder, t, iso, MIN_DARK_FRAMES, seed + 1, None)
        bundle.add_dark(dark, t, iso, provenance(frames=MIN_DARK_FRAMES, for_flat=True, **prov))
    flat = flat_field(flats, dark=dark)
    bundle.set_flat(flat, provenance(frames=n, exposure_s=t, iso=iso, fill=FLAT_FILL, **prov))
    bad = bad_pixel_map(flats[0].cfa_pattern, dark=dark, flat=flat)
    bundle.set_bad_pixels(bad, provenance(with_flat=True, **prov))
    return CalibrationRun("flat", bundle.path, n, {"exposure_s": t, "iso": iso,
                                                   "min": float(flat.min()),
                                                   "max": float(flat.max()),
                                                   "bad_pixels": int(bad.sum())})


def _noise(dev, planner, joints, bundle, folder, prov, *, exposure, iso, frames, seed, progress,
           rig) -> CalibrationRun:
    levels = frames or 8
    cam = _Frames(dev, "uniform", folder, iso, progress, 2 * levels + 2, seed)
    t_top = _expose_for_fill(lambda e: cam.take(e, "test"), exposure, 0.8)
    pairs = []
    for k in range(levels):
        t = t_top * 2.0 ** (-(levels - 1 - k) * 6.0 / max(levels - 1, 1))  # 1.6 % … 80 % fill
        pairs.append((cam.take(t, "ptc"), cam.take(t, "ptc")))
    cap = _Frames(dev, "cap", folder, iso, None, 2, seed + 2)
    pairs.insert(0, (cap.take(t_top / 64, "ptc-dark"), cap.take(t_top / 64, "ptc-dark")))
    ptc = photon_transfer(pairs)
    gain, read = ptc.model.per_colour()
    bundle.set_noise(ptc.model, provenance(pairs=len(pairs), longest_exposure_s=t_top,
                                           residual_rms=ptc.residual_rms.tolist(), **prov))
    return CalibrationRun("noise", bundle.path, 2 * len(pairs),
                          {"iso": iso, "gain_e_per_dn": gain.tolist(),
                           "read_noise_dn": read.tolist()})


def _white(dev, planner, joints, bundle, folder, prov, *, exposure, iso, frames, seed, progress,
           rig: RigConfig) -> CalibrationRun:
    n = frames or WHITE_FRAMES
    cam = _Frames(dev, "white", folder, iso, progress, n, seed)
    x0, y0, x1, y1 = rig.camera.roi
    t = exposure
    images = []
    noise = bundle.noise_for(iso)
    dark = bundle.dark_for(t, iso)
    for _ in range(n):
        frame = cam.take(t, "white")
        image = linearize(frame, dark=dark, flat=bundle.flat, bad_pixels=bundle.bad_pixels,
                          noise=noise)
        if not image.valid[y0:y1, x0:x1].any():
            raise CalibrationError(
                f"white reference clips everywhere in the ROI at {t:g} s; pass a shorter --exposure"
            )
        images.append(image)
    white = measure_white(images, (x0, y0, x1 - x0, y1 - y0), rig.white_reference.reflectance,
                          rig.white_reference.theta_i, rig.light_distance_m)
    bundle.set_white({**white.to_dict(), "exposure_s": t, "iso": iso, "frames": n,
                      "with_dark": dark is not None, "with_flat": bundle.flat is not None},
                     provenance(**prov))
    return CalibrationRun("white", bundle.path, n, {"signal": white.signal.tolist(),
                                                    "exposure_s": t, "iso": iso})

