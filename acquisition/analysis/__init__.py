"""From table to insight: plots of plans and tables.

May import: everything below ``acquisition.api`` except ``acquisition.cli``.
"""
