"""Ground truth for simulated sessions: the material's BRDF binned at the measured geometry.

Binning the true BRDF at the same read-back poses as the measurement gives a table that
differs from the measured one only by measurement error, which is what tests and the demo
report (median relative error over measured bins).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acquisition.reduction.point import binning_pose
from acquisition.session.engine import POSE
from acquisition.session.folder import SessionFolder
from acquisition.simworld.materials import parse_material
from acquisition.tables import IsotropicTable
from simulators.materials import Material


def truth_table(session_dir: str | Path | SessionFolder, material: Material | None = None
                ) -> IsotropicTable:
    """The session's material evaluated at every captured pose, binned like the reduction
    (``session_dir``: the folder, or its opened :class:`SessionFolder`)."""
    folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
    if material is None:
        if not folder.info.material:
            raise ValueError(f"{folder.path} records no simulated material")
        material = parse_material(folder.info.material)
    plan, kin = folder.plan(), folder.rig().kinematics()
    table = IsotropicTable(plan.table.theta_i_edges, plan.table.theta_r_edges,
                           plan.table.delta_phi_edges, provenance={"truth": material.spec})
    with folder.journal(readonly=True) as journal:
        for rec in journal.steps():
            if rec.status != "done" or rec.kind != POSE:
                continue
            g = kin.forward_geometry(rec.joints_read or rec.joints_cmd)
            pose = binning_pose(rec)
            value = material.eval_vectors(g.light_dir, g.camera_dir)
            table.add(np.array([pose.theta_i]), np.array([pose.theta_r]),
                      np.array([pose.delta_phi]), value[None, :])
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
