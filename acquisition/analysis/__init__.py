"""From table to insight: plots of plans and tables.

May import: ``acquisition.geometry``, ``acquisition.planning``, ``acquisition.tables``,
``drivers.errors``, ``drivers.storage``.
"""
