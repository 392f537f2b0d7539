"""The simulated world: what the simulated camera sees (scene, its own optics, sample holder,
lamp drift, the true geometry of a misaligned rig), the light stage, materials, and starting
the simulators for a rig. The only room of ``acquisition`` that wires up ``simulators``. A
referee: it never imports the code it judges (the reduction, the planner, the calibration).

Measured materials (``merl:``, ``bsdf:``) are read and evaluated by
:mod:`simulators.measured`, not by ``acquisition.formats`` (whose readers and exporters it
judges through round trips).

May import: ``acquisition.geometry``, ``acquisition.config``, ``drivers.numba_cache``,
``simulators``, ``drivers``.
"""
