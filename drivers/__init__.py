"""Real hardware: the Dynamixel servo bus and axes, DMX widgets and lights, cameras;
:mod:`drivers.errors`, the one exception hierarchy, :mod:`drivers.storage`, the one file
writer (the disk is a device), and :mod:`drivers.numba_cache`, the upkeep of numba's on-disk
cache of compiled code (the simulators' kernels and the reduction's alike).

May import: nothing (the bottom layer).
"""
