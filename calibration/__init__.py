"""Radiometric calibration: RAW loading, linearization, dark, flat, noise, HDR, white
reference, bundles and EXR files (:mod:`calibration.exr`).

May import: ``drivers.errors``, ``drivers.storage``.
"""
