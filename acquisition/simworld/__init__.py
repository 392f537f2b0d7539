"""The simulated world: what the simulated camera sees (scene, sample holder, lamp drift), the
ground truth of a simulated material, and starting the simulators for a rig. The only room of
``acquisition`` that wires up ``simulators``.

May import: ``drivers``, ``simulators``, ``calibration``, ``acquisition.geometry``,
``acquisition.config``, ``acquisition.reduction.imaging``, ``acquisition.tables``.
"""
