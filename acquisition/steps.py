"""Step records of scripted sessions: the public import path documented in the README.

The code lives in :mod:`acquisition.session.steps`; this module re-exports it so that scripts
written against ``acquisition.steps`` keep working.
"""

from acquisition.session.steps import (
    CUSTOM,
    DARK,
    JOURNALED_KINDS,
    POSE,
    REFERENCE,
    Checkpoint,
    Custom,
    Dark,
    Expose,
    ExposeHDR,
    Move,
    Reference,
    Step,
    capture_steps,
    count_rows,
    journal_rows,
    pose_steps,
    sweep_steps,
)

__all__ = [
    "CUSTOM", "DARK", "JOURNALED_KINDS", "POSE", "REFERENCE", "Checkpoint", "Custom", "Dark",
    "Expose", "ExposeHDR", "Move", "Reference", "Step", "capture_steps", "count_rows",
    "journal_rows", "pose_steps", "sweep_steps",
]
