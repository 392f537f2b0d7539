"""Reduction: a session's RAW frames → linear signals → BRDF samples → isotropic table.

Each frame is linearized (black level, saturation mask, exposure), averaged over the region of
interest, and divided by the white reference interpolated in time between its captures (which
also corrects slow light drift). With the reference's reflectance ρ and its geometry, a sample
signal S at incidence θi gives

    f = (S / S_ref) · (ρ / π) · (cos θi_ref / cos θi)   [sr⁻¹]

because the pixel value is proportional to radiance L = f · E and the point light's
irradiance is E = I cos θi / r² at both geometries.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.linearize import linearize, roi_mean
from calibration.raw import load_raw
from drivers.errors import SessionError

from .journal import StepRecord
from .session import REFERENCE, SessionFolder
from .tables import IsotropicTable


@dataclass(frozen=True)
class FrameSignal:
    """The region-of-interest mean of one frame, DN/s per channel, and its variance."""

    step: int
    signal: np.ndarray
    variance: np.ndarray
    n_valid: int


@dataclass
class Reduction:
    """What :func:`reduce_session` produced."""

    table: IsotropicTable
    frames: int
    references: int
    drift_pct: float
    """Peak-to-peak change of the white reference over the session, % of its mean."""
    seconds: float


def frame_signal(path: Path, roi: tuple[int, int, int, int], step: int) -> FrameSignal:
    """Linearize a frame and average its region of interest."""
    image = linearize(load_raw(path))
    x0, y0, x1, y1 = roi
    mean, var, n = roi_mean(image, (x0, y0, x1 - x0, y1 - y0))
    return FrameSignal(step, np.asarray(mean, float), np.asarray(var, float), int(n))


def reference_curve(refs: list[FrameSignal]) -> Callable[[int], np.ndarray]:
    """White-reference signal at any step, interpolated linearly between its captures."""
    steps = np.array([r.step for r in refs], float)
    values = np.array([r.signal for r in refs])

    def at(step: int) -> np.ndarray:
        return np.array([np.interp(step, steps, values[:, c]) for c in range(values.shape[1])])

    return at


def reduce_session(
    session_dir: str | Path,
    progress: Callable[[int, int], None] | None = None,
) -> Reduction:
    """Linearize every captured frame of a session and bin it into its plan's table."""
    t0 = time.monotonic()
    folder = SessionFolder(session_dir)
    rig, plan = folder.rig(), folder.plan()
    kin = rig.kinematics()
    with folder.journal() as journal:
        records = [r for r in journal.steps() if r.status == "done"]
    if not records:
        raise SessionError(f"{folder.path} has no captured frame yet: run or resume the capture first")

    def signal(rec: StepRecord) -> FrameSignal:
        return frame_signal(folder.frames_dir / str(rec.frame), rig.camera.roi, rec.step)

    refs = [signal(r) for r in records if r.kind == REFERENCE]
    if not refs:
        raise SessionError(f"{folder.path} has no white-reference frame: resume the capture to take it")
    if any(r.n_valid == 0 for r in refs):
        raise SessionError(f"{folder.path}: a white-reference frame is saturated or dark in the ROI")
    ref_at = reference_curve(refs)
    ref_signals = np.array([r.signal for r in refs])
    drift = float(np.max(np.ptp(ref_signals, axis=0) / np.mean(ref_signals, axis=0)) * 100.0)

    wr = rig.white_reference
    rho = np.asarray(wr.reflectance, float)
    cos_ref = np.cos(np.radians(wr.theta_i))
    table = IsotropicTable(
        plan.table.theta_i_edges, plan.table.theta_r_edges, plan.table.delta_phi_edges,
        provenance={
            "session": str(folder.path.resolve()),
            "rig": rig.name,
            "plan": plan.name,
            "material": folder.info.material,
            "seed": folder.info.seed,
            "reference_drift_pct": drift,
            "reduced_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        },
    )
    poses = [r for r in records if r.kind != REFERENCE]
    for k, rec in enumerate(poses):
        fs = signal(rec)
        pose = kin.forward(rec.joints_read or rec.joints_cmd)
        cos_i = np.cos(np.radians(pose.theta_i))
        if fs.n_valid == 0 or cos_i <= 0:
            continue
        f = fs.signal / ref_at(rec.step) * (rho / np.pi) * (cos_ref / cos_i)
        table.add(
            np.array([pose.theta_i]), np.array([pose.theta_r]), np.array([pose.delta_phi]),
            f[None, :],
        )
        if progress:
            progress(k + 1, len(poses))
    return Reduction(table, len(poses), len(refs), drift, time.monotonic() - t0)
