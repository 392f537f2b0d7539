"""Measured materials from files, read and evaluated with the simulator's own code: MERL
``.binary`` files (:mod:`simulators.measured.merl`) and RGL-EPFL ``.bsdf`` files
(:mod:`simulators.measured.rgl`, on :mod:`simulators.measured.tensor` and
:mod:`simulators.measured.warp`).

gonio's exporters and its MERL table write these formats with gonio's own half/difference
coordinates and warps; a simulated camera that evaluated a file through them would agree
with their bugs. These modules are written from the formats' public descriptions (the MERL
database's reference reader, Dupuy & Jakob 2018 and Mitsuba 3's ``measured`` plug-in) and
share no code with ``acquisition``; tests compare the two implementations.
"""
