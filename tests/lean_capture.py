"""Capture the example plans on one rig, lean: a child process of ``test_plan_captures``.

``python tests/lean_capture.py RIG OUT`` runs ``api.capture`` of plan-quick, plan-demo and
plan-dense (``examples/``) on ``examples/RIG.toml`` into ``OUT/PLAN``, with what cannot change
where an arm goes made cheap (see :func:`make_lean`), prints one line per capture and exits 1
if the simulator recorded any contact of the arms (listed on stderr, as the simulator's own
warnings are).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
PLANS = ("plan-quick", "plan-demo", "plan-dense")
CONTROL_CYCLE_S = 0.1
"""Read-back interval of the motion controller while a move runs (gonio's is 10 ms)."""


def make_lean(frame_dir: Path) -> None:
    """The economies, none of which changes a trajectory:

    - the simulated camera writes the smallest DNG the readers accept (22 × 22 px) for every
      exposure instead of rendering the scene (the rig clock still runs for the exposure), and
      the region of interest is never clipped (no retakes);
    - the motion controller reads back every :data:`CONTROL_CYCLE_S` instead of every 10 ms
      while a move runs: each move still starts at rest from one sync write and follows the
      servos' own trapezoids, and a lost goal is still seen at the first read-back, right after
      the write; only the idle time before the next move grows.
    """
    from acquisition.devices import servos
    from acquisition.devices.rig import RigDevices
    from drivers.camera import CaptureInfo
    from simulators.camera import SimCamera
    from simulators.dng import MIN_SIZE_PX, write_dng

    frame = write_dng(frame_dir / "smallest.dng", np.full((MIN_SIZE_PX, MIN_SIZE_PX), 600,
                                                          dtype=np.uint16),
                      black_level=512, white_level=16383, exposure_s=0.01, iso=100).read_bytes()

    def capture(self: SimCamera, path: str | os.PathLike[str], exposure_s: float,
                iso: float = 100.0, *, frame_seed: int | None = None) -> CaptureInfo:
        with self._lock, self._frozen():
            start = self._clock.now() if self._clock is not None else 0.0
            Path(path).write_bytes(frame)
            if self._clock is not None:
                self._clock.advance(exposure_s)
            self._frames += 1
        return CaptureInfo(path=Path(path), exposure_s=float(exposure_s), iso=float(iso),
                           timestamp=start)

    SimCamera.capture = capture  # type: ignore[method-assign]
    RigDevices.roi_saturated = lambda self, frame: False  # type: ignore[method-assign]
    servos.MOTION_POLL_S = CONTROL_CYCLE_S  # type: ignore[misc]


def main(rig: str, out: Path) -> int:
    from acquisition import api
    from simulators.dynamixel import drain_collisions

    out.mkdir(parents=True, exist_ok=True)
    make_lean(out)
    hits = []
    for plan in PLANS:
        t0 = time.monotonic()
        result = api.capture(EXAMPLES / f"{rig}.toml", EXAMPLES / f"{plan}.toml", out / plan,
                             material="lambert:albedo=0.5", seed=1)
        hits += drain_collisions()
        print(f"{rig} {plan}: {sum(result.counts.values())} steps in "
              f"{time.monotonic() - t0:.1f} s", flush=True)
    for hit in hits:
        print(hit, file=sys.stderr)
    return 1 if hits else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], Path(sys.argv[2])))
