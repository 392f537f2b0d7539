"""The simulated world: what the simulated camera sees (scene, sample holder, lamp drift, the
true geometry of a misaligned rig), the light stage, materials, the ground truth of a simulated
material, and starting the simulators for a rig. The only room of ``acquisition`` that wires
up ``simulators``.

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.session``,
``acquisition.reduction``, ``acquisition.tables``, ``acquisition.formats``, ``simulators``,
``drivers``.
"""
