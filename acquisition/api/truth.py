"""Ground truth for simulated sessions: the material's BRDF binned at the measured geometry.

Binning the true BRDF at the poses the reduction gives its samples (the read-back joints
through the same geometry model: the rig file's, or the geometric calibration's) gives a
table that differs from the measured one only by measurement error — the angular error of a
misaligned rig included — which is what tests and the demo report (median relative error over
measured bins).

It is no part of the simulated world (which never calls the code it judges): it pairs the
reduction's own claims — where each sample was taken and the bin it goes to
(:class:`~acquisition.reduction.samplegeometry.SampleGeometry`) — with the simulated material
evaluated at the claimed directions. A wrong claimed direction shows as an error, since the
measured radiance comes from the simulator's true geometry; a sample put in the wrong bin for
the right direction does not, since both tables bin alike.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acquisition.geometry.kinematics import poses_from_directions
from acquisition.reduction.image import iter_session_samples
from acquisition.reduction.point import find_bundle
from acquisition.reduction.samplegeometry import SampleGeometry
from acquisition.session.engine import POSE
from acquisition.session.folder import SessionFolder
from acquisition.simworld.materials import parse_material
from acquisition.tables import IsotropicTable

if TYPE_CHECKING:
    from simulators.materials import Material


def truth_table(session_dir: str | Path | SessionFolder, material: Material | None = None,
                *, bundle: str | Path | None = None, geometry: bool = True) -> IsotropicTable:
    """The session's material evaluated at every captured pose, binned like the reduction
    (``session_dir``: the folder, or its opened :class:`SessionFolder`; ``bundle`` and
    ``geometry`` as for :func:`~acquisition.reduction.point.reduce_session`: the poses are
    those the reduction claims)."""
    folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
    if material is None:
        if not folder.info.material:
            raise ValueError(f"{folder.path} records no simulated material")
        material = parse_material(folder.info.material)
    plan = folder.plan()
    geo = SampleGeometry.of(folder.rig(), find_bundle(folder, bundle), calibrated=geometry)
    table = IsotropicTable(plan.table.theta_i_edges, plan.table.theta_r_edges,
                           plan.table.delta_phi_edges, provenance={"truth": material.spec})
    with folder.journal(readonly=True) as journal:
        for rec in journal.steps():
            if rec.status != "done" or rec.kind != POSE:
                continue
            g = geo.kinematics.forward_geometry(rec.joints_read or rec.joints_cmd)
            pose = geo.bin_pose(rec)
            value = material.eval_vectors(g.light_dir, g.camera_dir)
            table.add(np.array([pose.theta_i]), np.array([pose.theta_r]),
                      np.array([pose.delta_phi]), value[None, :])
    return table


def image_truth_table(session_dir: str | Path, material: Material | None = None, *,
                      bundle: str | Path | None = None) -> IsotropicTable:
    """An image-based session's material evaluated at every pixel the reduction keeps, at the
    geometry it claims for it (its calibrated model, ``bundle`` as for
    :func:`~acquisition.reduction.image.reduce_image_session`), binned like the reduction:
    the measured table differs from it by the measurement's errors only (where the pixels fell
    within a bin is the same in both)."""
    folder = SessionFolder(session_dir)
    if material is None:
        if not folder.info.material:
            raise ValueError(f"{folder.path} records no simulated material")
        material = parse_material(folder.info.material)
    plan = folder.plan()
    table = IsotropicTable(plan.table.theta_i_edges, plan.table.theta_r_edges,
                           plan.table.delta_phi_edges, provenance={"truth": material.spec})
    for fs in iter_session_samples(folder.path, bundle=bundle):
        angles = poses_from_directions(fs.wi, fs.wo)
        keep = np.all(np.isfinite(fs.brdf), axis=1)  # the pixels the reduction bins
        table.add(angles[keep, 0], angles[keep, 1], angles[keep, 2],
                  material.eval_vectors(fs.wi[keep], fs.wo[keep]))
    return table


def relative_errors(measured: IsotropicTable, truth: IsotropicTable) -> np.ndarray:
    """|measured − truth| / truth per bin both hold, averaged over the RGB channels.

    Bins where the truth is unknown are left out: a measured material's unmeasured bins
    (a MERL file's negative values, which the simulated material evaluates as 0) have no
    relative error to speak of.
    """
    known = np.all(np.isfinite(truth.mean) & (truth.mean > 0), axis=-1)
    mask = (measured.count > 0) & (truth.count > 0) & known
    m, t = measured.mean[mask], truth.mean[mask]
    return np.mean(np.abs(m - t) / t, axis=-1)
