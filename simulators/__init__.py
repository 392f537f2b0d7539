"""Simulated devices that speak the real wire protocols (Dynamixel 2.0 and DMX on a pty, DNG
files), the simulated clock, the rig's solid parts (:mod:`simulators.rig_solids`, geometry of
their own) and the gears between servos and arms (:mod:`simulators.dynamixel.drivetrain`:
zero offsets, backlash, position noise), the sensor and the reference materials.

May import: ``drivers.errors``, ``drivers.camera``.
"""
