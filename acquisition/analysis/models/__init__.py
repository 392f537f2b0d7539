"""Analytic BRDF models from the lecture, with energy-conserving fit bounds.

May import: ``acquisition.geometry``, ``drivers.errors``, ``drivers.storage``.
"""

from acquisition.analysis.models.base import CHANNELS, Model, Param
from acquisition.analysis.models.library import MODEL_NAMES, make_model

__all__ = ["CHANNELS", "MODEL_NAMES", "Model", "Param", "make_model"]
