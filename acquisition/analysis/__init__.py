"""From table to insight: the lecture's BRDF models (``models``), weighted fits with 1σ
(``fit``), physical checks (``checks``), comparisons (``compare``), plots and the HTML report.

May import: ``acquisition.geometry``, ``acquisition.planning``, ``acquisition.tables``,
``acquisition.formats``, ``drivers.errors``, ``drivers.storage``.
"""
