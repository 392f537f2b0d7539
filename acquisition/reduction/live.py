"""A BRDF estimate while the capture runs: an observer of the session engine."""

from __future__ import annotations

import numpy as np

from acquisition.geometry.kinematics import Pose
from acquisition.reduction.point import frame_signal
from acquisition.session.engine import StepEvent
from acquisition.session.folder import SessionFolder
from acquisition.session.observers import Observer
from acquisition.session.steps import POSE, REFERENCE
from acquisition.tables import IsotropicTable


class LiveReduction(Observer):
    """A BRDF estimate while the capture runs.

    Each pose frame is linearized and divided by the latest white-reference frame (the final
    reduction interpolates the reference in time instead), binned into an isotropic table with
    the plan's bins. Frames taken before this observer started (a resumed run) are not seen.

    Attributes
    ----------
    table
        The running :class:`~acquisition.tables.IsotropicTable` (sr⁻¹), None before start.
    samples
        ``(pose, rgb)`` per binned frame: pose in degrees (from the read-back joints), BRDF in
        sr⁻¹.
    """

    def __init__(self) -> None:
        self.table: IsotropicTable | None = None
        self.samples: list[tuple[Pose, np.ndarray]] = []
        self._ref: np.ndarray | None = None

    def start(self, folder: SessionFolder, total: int | None, done: int) -> None:
        self._folder = folder
        rig, plan = folder.rig(), folder.plan()
        self._rig = rig
        self._kin = rig.kinematics()
        if self.table is None:
            t = plan.table
            self.table = IsotropicTable(t.theta_i_edges, t.theta_r_edges, t.delta_phi_edges,
                                        provenance={"live": True, "session": str(folder.path)})

    def step(self, event: StepEvent) -> None:
        rec = event.record
        if event.frame is None or rec.kind not in (POSE, REFERENCE):
            return
        fs = frame_signal(event.frame, self._rig.camera.roi, rec.step)
        if fs.n_valid == 0:
            return
        if rec.kind == REFERENCE:
            self._ref = fs.signal
            return
        if self._ref is None:
            return
        pose = self._kin.forward(rec.joints_read or rec.joints_cmd)
        cos_i = np.cos(np.radians(pose.theta_i))
        if cos_i <= 0:
            return
        wr = self._rig.white_reference
        rho = np.asarray(wr.reflectance, float)
        f = fs.signal / self._ref * (rho / np.pi) * (np.cos(np.radians(wr.theta_i)) / cos_i)
        assert self.table is not None
        self.table.add(pose.theta_i, pose.theta_r, pose.delta_phi, f[None, :])
        self.samples.append((pose, f))

    def peak(self, channel: int = 1) -> Pose:
        """The measured pose (degrees) with the largest BRDF in ``channel`` (default green)."""
        if not self.samples:
            raise ValueError("no pose frame reduced yet")
        best = max(self.samples, key=lambda s: float(s[1][channel]))
        return best[0]
