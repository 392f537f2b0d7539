"""Simulated devices that speak the real wire protocols (Dynamixel 2.0 on a pty, DNG files),
plus the reference materials. May import :mod:`drivers.errors` only."""
