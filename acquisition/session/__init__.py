"""Capture sessions: the folder, its SQLite journal, step records, the engine that runs them on
open devices, observers, the Ctrl-C handler, and the status report.

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.planning``,
``calibration``, ``drivers.errors``, ``drivers.storage``.
"""
