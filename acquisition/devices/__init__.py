"""Opening a rig's devices (real or simulated) behind one interface, the motion guard every
move passes, servo health, and the operator console's verbs.

May import: ``drivers``, ``calibration``, ``acquisition.geometry``, ``acquisition.config``,
``acquisition.planning``, ``acquisition.simworld`` (to start simulated devices).
"""
