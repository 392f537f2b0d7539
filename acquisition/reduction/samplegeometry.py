"""Where a reduction says each sample was taken: the rig file's kinematics, corrected by the
geometric calibration of the bundle it applies (``gonio calibrate geometry``) and by the
backlash the rig file states for any axis the calibration did not measure.

Backlash: a rig stating it approaches every target from one side
(:mod:`acquisition.geometry.approach`), so each arm stands b/2 behind its commanded angle on
the side :func:`~acquisition.geometry.approach.approach_signs` gives, every frame alike — an
offset to correct, not a scatter. A calibration's measured backlash is corrected with its
offsets; a stated one (``[axes.NAME] backlash_deg``) the same way
(:attr:`SampleGeometry.stated_backlash_deg`), its uncertainty budgeted by
:mod:`acquisition.reduction.angular`.

Without a correction a sample is binned at its commanded pose (the plan's) and its value uses
the read-back pose (cos θi, the bin's mean angles). With one, the read-back joints go through
the corrected model (zero offsets, sample tilt, backlash) and the sample is binned at the pose
its commanded joints realise on the real rig — the plan's pose when the capture planned with
the same calibration, the pose the arms really took when it did not (a bundle made later, a
stated backlash the planner leaves to the reduction).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.kinematics import Kinematics, Pose
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.session.alignment import alignment_of
from acquisition.session.journal import StepRecord
from calibration.bundle import CalibrationBundle

DEGENERATE_DEG = 1e-6
"""A commanded θ this close to the normal leaves Δφ undefined: the command's Δφ bins it."""


@dataclass(frozen=True)
class SampleGeometry:
    """The reduction's geometry model (see the module docstring)."""

    base: Kinematics
    """The rig file's kinematics."""
    kinematics: Kinematics
    """``base``, or ``base`` corrected by :attr:`corrections`."""
    alignment: Alignment | None
    """The geometric calibration applied, if any."""
    stated_backlash_deg: Mapping[str, float] = field(default_factory=dict)
    """The rig file's backlash (deg) of the axes the calibration did not measure, corrected."""

    @classmethod
    def of(cls, rig: RigConfig, bundle: CalibrationBundle | None, *, calibrated: bool = True
           ) -> SampleGeometry:
        """The model of ``rig`` with ``bundle``'s geometric calibration (unless
        ``calibrated`` is False: the rig file's model, as without a calibration) and the rig
        file's stated backlash (module docstring)."""
        base = rig.kinematics()
        if not base.moving_arms:
            return cls(base, base, None)
        alignment = alignment_of(bundle, rig) if calibrated else None
        measured = {} if alignment is None else alignment.backlash_deg
        stated = {n: rig.axes[n].backlash_deg for n in base.joint_names
                  if n not in measured and n in rig.axes and rig.axes[n].backlash_deg > 0}
        if alignment is None and not stated:
            return cls(base, base, None)
        corrections = alignment or Alignment()
        corrections = replace(corrections, backlash_deg={**corrections.backlash_deg, **stated})
        return cls(base, CalibratedKinematics(base, corrections), alignment, stated)

    @property
    def corrections(self) -> Alignment | None:
        """What :attr:`kinematics` applies: the calibration and the stated backlash."""
        kin = self.kinematics
        return kin.alignment if isinstance(kin, CalibratedKinematics) else None

    @property
    def pointing_deg(self) -> tuple[float, float]:
        """The camera's calibrated pointing error (image-based rigs), deg."""
        return (0.0, 0.0) if self.alignment is None else self.alignment.camera_pointing_deg

    def read_back(self, rec: StepRecord) -> Pose:
        """The pose of the step's read-back joints (its commanded ones if none were read)."""
        return self.kinematics.forward(rec.joints_read or rec.joints_cmd)

    def bin_pose(self, rec: StepRecord) -> Pose:
        """The pose the step's sample is binned at (see the module docstring)."""
        commanded = Pose(rec.theta_i, rec.theta_r, rec.delta_phi)
        if self.corrections is None or not rec.joints_cmd:
            return commanded
        realised = self.kinematics.forward(rec.joints_cmd)
        if min(commanded.theta_i, commanded.theta_r) < DEGENERATE_DEG:
            return Pose(realised.theta_i, realised.theta_r, commanded.delta_phi)
        return realised

    def joints_array(self, records: list[StepRecord]) -> np.ndarray:
        """The read-back joints (N, J) of ``records``, in the kinematics' joint order."""
        names = self.kinematics.joint_names
        if not records:
            return np.zeros((0, len(names)))
        return np.array([[float((r.joints_read or r.joints_cmd)[n]) for n in names]
                         for r in records])
