"""Rig, plan, light-stage and dome files: TOML sections, validation, the frozen config objects
every later stage reads, and the simulated sensor's parameters.

May import: ``acquisition.geometry``, ``drivers``, ``calibration``, ``simulators.sensor``.
"""
