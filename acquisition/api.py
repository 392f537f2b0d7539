"""The Python API behind the CLI: what a researcher's capture script calls.

>>> from acquisition.api import capture, reduce
>>> capture("examples/rig-sim.toml", "examples/plan-quick.toml", "runs/s1",
...         material="lambert:albedo=0.5", seed=1)            # doctest: +SKIP
>>> reduce("runs/s1", "runs/s1/brdf.h5").table.count.sum()    # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import acquisition.merl  # noqa: F401  (registers the merl:PATH material)
from drivers.errors import SessionError
from simulators.materials import material_from_spec

from .devices import open_devices
from .journal import StepRecord
from .kinematics import Pose
from .plan import load_plan
from .planner import Planner, Sweep  # noqa: F401  (re-exported)
from .reduce import Reduction, reduce_session
from .rig import load_rig
from .session import CaptureEngine, SessionFolder, create_session

DEFAULT_MATERIAL = "ggx:albedo=0.2,alpha=0.3,f0=0.04"

Progress = Callable[[int, int, StepRecord], None]


@dataclass
class CaptureResult:
    """Where a capture went and how it ended."""

    session: SessionFolder
    counts: dict[str, int]
    device_seconds: float | None
    """Time the capture took on the devices' clock (the simulated clock for simulated rigs)."""


def plan_sweep(plan_path: str | Path, rig_path: str | Path) -> Sweep:
    """Plan a sweep without moving anything: accepted/rejected poses and the time estimate."""
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    wr = rig.white_reference
    start = planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi))
    return planner.plan(plan.poses(), start)


def run_session(
    folder: SessionFolder,
    *,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
    on_open: Callable[[SessionFolder, float | None], None] | None = None,
) -> CaptureResult:
    """Run (or continue) every step of a session that is not done yet."""
    rig = folder.rig()
    material = material_from_spec(folder.info.material) if folder.info.material else None
    if rig.simulated and material is None:
        raise SessionError(f"{folder.path}: a simulated rig needs a material (--material)")
    planner = Planner.for_plan(rig, folder.plan())
    with open_devices(rig, planner, material=material, seed=folder.info.seed,
                      sim_faults=sim_faults) as devices:
        if on_open:
            on_open(folder, devices.device_time_s())
        t0 = devices.device_time_s()
        engine = CaptureEngine(folder, devices, devices.roi_saturated, progress)
        counts = engine.run()
        t1 = devices.device_time_s()
    return CaptureResult(folder, counts, None if t0 is None or t1 is None else t1 - t0)


def capture(
    rig_path: str | Path,
    plan_path: str | Path,
    out: str | Path,
    *,
    material: str | None = None,
    seed: int = 0,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
) -> CaptureResult:
    """Create a session folder at ``out`` and capture the plan on the rig."""
    rig = load_rig(rig_path)
    if rig.simulated:
        material = material or DEFAULT_MATERIAL
        material_from_spec(material)  # fail before creating anything
    folder, _ = create_session(out, rig_path, plan_path, material=material, seed=seed)
    return run_session(folder, sim_faults=sim_faults, progress=progress)


def resume(
    session_dir: str | Path,
    *,
    sim_faults: Sequence[str] = (),
    progress: Progress | None = None,
) -> CaptureResult:
    """Continue an interrupted session where it stopped."""
    return run_session(SessionFolder(session_dir), sim_faults=sim_faults, progress=progress)


def reduce(
    session_dir: str | Path,
    table_path: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Reduction:
    """Reduce a session into its isotropic BRDF table, saved as HDF5 (default: DIR/brdf.h5)."""
    result = reduce_session(session_dir, progress)
    out = Path(table_path) if table_path else Path(session_dir) / "brdf.h5"
    result.table.save_h5(out)
    return result
