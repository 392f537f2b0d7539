"""Reduction of a session's frames into BRDF tables: point (ROI) and per-pixel reduction,
the imaging geometry of image-based rigs, and the live estimate.

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.session``,
``acquisition.tables``, ``acquisition.formats``, ``calibration``, ``drivers.errors``.
"""
