"""Files other tools read: MERL binaries, CSV and EXR exports of BRDF tables, RGL-EPFL ``.bsdf``
files (Mitsuba 3's ``measured`` material), environment maps.

May import: ``acquisition.geometry``, ``acquisition.tables``, ``calibration.exr``,
``drivers.errors``, ``drivers.storage``.
"""
