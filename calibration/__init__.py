"""Radiometric calibration: RAW loading, linearization, dark, flat, noise, HDR, white
reference, bundles and EXR files (:mod:`calibration.exr`); the geometric calibration's
mathematics: peak location (:mod:`calibration.peaks`) and least squares that names what it
cannot determine (:mod:`calibration.lsq`).

May import: ``drivers.errors``, ``drivers.storage``.
"""
