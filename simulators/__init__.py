"""Simulated devices that speak the real wire protocols (Dynamixel 2.0 on a pty, DNG files),
the rig's solid parts (:mod:`simulators.rig_solids`, geometry of their own), plus the reference
materials. May import :mod:`drivers.errors` only."""
