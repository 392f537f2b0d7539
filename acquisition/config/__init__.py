"""Rig and plan files: TOML sections, validation, the frozen config objects every later stage
reads.

May import: ``drivers.errors``, ``acquisition.geometry``.
"""
