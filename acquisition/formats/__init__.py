"""Files other tools read: MERL binaries, CSV and EXR exports of BRDF tables, environment maps.

May import: ``acquisition.geometry``, ``acquisition.tables``, ``calibration.exr``,
``drivers.errors``, ``drivers.storage``.
"""
