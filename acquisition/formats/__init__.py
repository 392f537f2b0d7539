"""Files other tools read: MERL binaries, CSV and EXR exports of BRDF tables.

May import: ``drivers.errors``, ``acquisition.geometry``, ``acquisition.tables``.
"""
