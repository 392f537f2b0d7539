"""Reduction of a session's frames into BRDF tables: point (ROI) and per-pixel reduction,
the imaging geometry of image-based rigs, the geometric calibration's model of where each
sample was taken, its angular uncertainty, the live estimate, and reduction on a Dask cluster
(``distributed``: the optional extra ``gonio[distributed]``, imported only when asked for).

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.session``,
``acquisition.tables``, ``acquisition.formats``, ``drivers.numba_cache``, ``calibration``,
``drivers.errors``.
"""

CHECKPOINT_EVERY = 10
"""Frames an image-based reduction bins between two checkpoints of its partial tables
(:mod:`acquisition.reduction.checkpoint`; ``gonio reduce --checkpoint-every``)."""
