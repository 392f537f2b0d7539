"""MERL BRDF files: the public import path documented for scripts (``read_merl``,
``write_merl``, ``MerlBRDF``). The code lives in :mod:`acquisition.formats.merl`."""

from acquisition.formats.merl import MERL_FILE_BYTES, MerlBRDF, read_merl, write_merl

__all__ = ["MERL_FILE_BYTES", "MerlBRDF", "read_merl", "write_merl"]
