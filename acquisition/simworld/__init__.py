"""The simulated world: what the simulated camera sees (scene, its own optics, sample holder,
lamp drift, the true geometry of a misaligned rig), the light stage, materials, and starting
the simulators for a rig. The only room of ``acquisition`` that wires up ``simulators``. A
referee: it never imports the code it judges (the reduction, the planner, the calibration).

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.formats``,
``simulators``, ``drivers``.
"""
