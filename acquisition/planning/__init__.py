"""Planning a sweep before anything moves: which poses are safe and useful (planner), in what
order (ordering), and how long it takes (time model).

May import: ``drivers.errors``, ``acquisition.geometry``, ``acquisition.config``.
"""
