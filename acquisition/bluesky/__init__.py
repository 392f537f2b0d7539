"""bluesky devices and plans over gonio's own drivers (the optional extra ``gonio[bluesky]``).

:func:`open_rig_devices` opens a rig file's devices — real or simulated — as ophyd-async
devices: each servo axis and the (θi, θr, Δφ) pose (movable, readable, every move through
gonio's motion guard), the RAW camera (triggerable; its reading names the frame it saved) and a
light stage's LEDs (settable as one array). :func:`brdf_sweep` captures a plan file with the
RunEngine into an ordinary gonio session folder, pausable at every step.

ophyd-async rather than ophyd: the RunEngine already runs plans on its asyncio loop, and
ophyd-async devices are coroutines there, with statuses (``AsyncStatus``) that complete when
gonio's blocking call returns on the rig's one worker thread; ophyd's threaded devices would
add a second concurrency model next to that thread and the RunEngine's loop.

May import: ``acquisition.api``, ``acquisition.config``, ``acquisition.devices``,
``acquisition.geometry``, ``acquisition.lightstage``, ``acquisition.planning``,
``acquisition.session``, ``acquisition.simworld``, ``drivers``.
"""

from acquisition.bluesky.plans import brdf_sweep
from acquisition.bluesky.rig import GonioDevices, open_rig_devices

__all__ = ["GonioDevices", "brdf_sweep", "open_rig_devices"]
