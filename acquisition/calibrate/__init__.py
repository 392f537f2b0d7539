"""Calibration procedures run on the rig (dark, flat, noise, white; geometry: zero offsets,
sample tilt, backlash, camera pointing); the math lives in the ``calibration`` package.

May import: ``acquisition.config``, ``acquisition.planning``, ``acquisition.devices``,
``acquisition.simworld``, ``acquisition.geometry``, ``calibration``, ``drivers``.
"""
