"""Light stage: a dome of LEDs over DMX, one-light-at-a-time capture, reflectance fields,
per-LED calibration and image-based relighting.

Modules: :mod:`.config` (dome, DMX wiring and simulation settings from the rig file),
:mod:`.devices` (widgets, lights, camera), :mod:`.sequences` (OLAT and pattern frames as
data, time estimate), :mod:`.capture` (durable sessions), :mod:`.reduce` (per-LED calibration,
BRDF table), :mod:`.field` (reflectance field EXRs), :mod:`.relight` and :mod:`.envmap`.

May import: ``acquisition.geometry``, ``acquisition.config``, ``acquisition.planning``,
``acquisition.session``, ``acquisition.reduction``, ``acquisition.simworld``,
``acquisition.devices``, ``acquisition.tables``, ``acquisition.formats``, ``calibration``,
``drivers``.
"""
