"""Radiometric (RAW linearization, dark, flat, noise, HDR, white reference) and geometric
calibration. May import :mod:`drivers` (errors, camera interface), never :mod:`acquisition`."""
