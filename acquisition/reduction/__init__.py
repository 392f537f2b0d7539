"""Reduction of a session's frames into BRDF tables: point (ROI) and per-pixel reduction,
and the imaging geometry of image-based rigs.

May import: ``drivers.errors``, ``calibration``, ``acquisition.geometry``,
``acquisition.config``, ``acquisition.planning``, ``acquisition.session``,
``acquisition.tables``, ``acquisition.formats``.
"""
