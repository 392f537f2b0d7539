"""Simulated Dynamixel X-series servos speaking Protocol 2.0 on a pseudo-terminal.

Entry points: :class:`SimServoBus` (start a bare bus, get its pty path, reach each
:class:`SimServo`), :func:`serve_rig` / :class:`SimRig` (a rig file's servos with its solid
parts, :mod:`simulators.dynamixel.rig`), :func:`serve_servos_forever` and
:func:`serve_rig_forever` (``gonio sim servos``, :mod:`simulators.dynamixel.serve`) and
:func:`parse_fault` (fault specs shared by the CLI and Python); :func:`drain_collisions` hands
a referee every contact of simulated arms in the process.
"""

from simulators.dynamixel.bus import SimServoBus, drain_collisions
from simulators.dynamixel.faults import Direction, Fault, parse_fault, parse_faults
from simulators.dynamixel.rig import SimRig, serve_rig
from simulators.dynamixel.serve import serve_rig_forever, serve_servos_forever
from simulators.dynamixel.servo import SimServo
from simulators.dynamixel.world import Collision, SolidWorld

__all__ = ["Collision", "Direction", "Fault", "SimRig", "SimServo", "SimServoBus", "SolidWorld",
           "drain_collisions", "parse_fault", "parse_faults", "serve_rig", "serve_rig_forever",
           "serve_servos_forever"]
