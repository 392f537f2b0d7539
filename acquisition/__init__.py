"""Rig kinematics, motion planner, capture sessions, BRDF tables and the ``gonio`` CLI.
The top layer: may import every other package; only :mod:`acquisition.cli` prints."""
