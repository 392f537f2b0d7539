"""Simulated Dynamixel X-series servos speaking Protocol 2.0 on a pseudo-terminal.

Entry points: :class:`SimServoBus` (start a bus, get its pty path, reach each
:class:`SimServo`), :func:`serve_servos_forever` (``gonio sim servos``) and
:func:`parse_fault` (fault specs shared by the CLI and Python).
"""

from simulators.dynamixel.bus import SimServoBus, serve_servos_forever
from simulators.dynamixel.faults import Fault, parse_fault, parse_faults
from simulators.dynamixel.servo import SimServo

__all__ = ["Fault", "SimServo", "SimServoBus", "parse_fault", "parse_faults",
           "serve_servos_forever"]
