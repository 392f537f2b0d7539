"""Real hardware: the Dynamixel servo bus and axes, DMX widgets and lights, cameras;
:mod:`drivers.errors`, the one exception hierarchy, and :mod:`drivers.storage`, the one file
writer (the disk is a device).

May import: nothing (the bottom layer).
"""
