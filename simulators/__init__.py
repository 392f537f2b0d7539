"""Simulated devices that speak the real wire protocols (Dynamixel 2.0 and DMX on a pty, DNG
files), the simulated clock, the rig's solid parts (:mod:`simulators.rig_solids`, geometry of
their own) and the gears between servos and arms (:mod:`simulators.dynamixel.drivetrain`:
zero offsets, backlash, position noise), the sensor, the reference materials and measured
materials from files (:mod:`simulators.measured`: MERL and RGL ``.bsdf``, read and evaluated
with code of their own).

May import: ``drivers.errors``, ``drivers.camera``, ``drivers.numba_cache``.
"""
