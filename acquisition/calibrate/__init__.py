"""Calibration procedures run on the rig (dark, flat, noise, white); the math lives in the
``calibration`` package.

May import: ``acquisition.config``, ``acquisition.planning``, ``acquisition.devices``,
``acquisition.simworld``, ``acquisition.geometry``, ``calibration``, ``drivers``.
"""
