"""Opening a rig's bluesky devices: :func:`open_rig_devices`.

A servo rig gives one :class:`~acquisition.bluesky.axes.GonioAxis` per axis, the
:class:`~acquisition.bluesky.axes.GonioPose` and the
:class:`~acquisition.bluesky.camera.GonioCamera`; a light stage its camera and its
:class:`~acquisition.bluesky.leds.LedDome`. Simulated devices start as ``gonio capture``
starts them (servo simulators on pseudo-terminals, the simulated camera rendering the
material), and the same code drives real ones.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from acquisition.bluesky.axes import GonioAxis, GonioPose
from acquisition.bluesky.camera import GonioCamera
from acquisition.bluesky.leds import LedDome
from acquisition.bluesky.link import RigLink
from acquisition.bluesky.session import END, SweepRequest
from acquisition.bluesky.worker import RigWorker
from acquisition.config.rig import RigConfig, load_rig
from acquisition.devices.rig import OperatorPrompt, RigDevices, open_devices
from acquisition.geometry.kinematics.lightstage import LightStage
from acquisition.lightstage.devices import LightStageDevices, open_lightstage
from acquisition.planning.planner import Planner
from acquisition.simworld.materials import DEFAULT_MATERIAL, parse_material


@dataclass
class GonioDevices:
    """The bluesky devices of one open rig (see :func:`open_rig_devices`)."""

    link: RigLink
    """Their shared state: gonio's open devices and the thread that alone calls them."""
    camera: GonioCamera
    axes: dict[str, GonioAxis] = field(default_factory=dict)
    """``{axis name: device}`` (empty on a light stage)."""
    pose: GonioPose | None = None
    """The (θi, θr, Δφ) pose device (None on a light stage)."""
    leds: LedDome | None = None
    """A light stage's LEDs (None on a servo rig)."""

    @property
    def rig(self) -> RigConfig:
        return self.link.rig

    def all(self) -> list[GonioAxis | GonioPose | GonioCamera | LedDome]:
        """Every device (e.g. to read them all, or for a table of names)."""
        extra: list[GonioPose | LedDome] = [d for d in (self.pose, self.leds) if d is not None]
        return [self.camera, *self.axes.values(), *extra]


@contextmanager
def open_rig_devices(
    rig_path: str | Path,
    *,
    material: str | None = None,
    seed: int = 0,
    frames_dir: str | Path | None = None,
    prompt: OperatorPrompt | None = None,
    sim_faults: Sequence[str] = (),
) -> Iterator[GonioDevices]:
    """Open the rig file's devices as bluesky devices; everything closes on exit.

    Parameters
    ----------
    rig_path
        The rig file (a simulated rig's simulators start as ``gonio capture`` starts them).
    material, seed
        The simulated camera's material spec (default: gonio's default material) and the
        simulated devices' noise seed; a sweep's session records both.
    frames_dir
        Where the camera writes frames triggered outside a :func:`brdf_sweep` (``None``: such
        a trigger fails, in one line).
    prompt
        Asks the operator to swap the sample and the white reference (a real camera).
    sim_faults
        Faults for the simulated servos (``gonio capture --sim-fault``'s specs).
    """
    rig = load_rig(rig_path)
    simulated_camera = rig.camera.driver == "simulated"
    spec = (material or DEFAULT_MATERIAL) if simulated_camera else material
    world = parse_material(spec) if simulated_camera and spec is not None else None
    with ExitStack() as stack:
        gonio: RigDevices | LightStageDevices
        if rig.kinematics_name == LightStage.name:
            gonio = stack.enter_context(open_lightstage(rig, material=world, seed=seed, prompt=prompt))
        else:
            gonio = stack.enter_context(open_devices(rig, Planner(rig), material=world, seed=seed,
                                                     sim_faults=sim_faults, prompt=prompt))
        worker = RigWorker()
        stack.callback(worker.close)
        link = RigLink(rig, gonio, worker, material=spec, seed=seed,
                       frames_dir=None if frames_dir is None else Path(frames_dir).absolute())
        stack.callback(_end_sweep, link)
        yield _devices(link)


def _devices(link: RigLink) -> GonioDevices:
    if isinstance(link.devices, LightStageDevices):
        return GonioDevices(link, GonioCamera(link), leds=LedDome(link))
    axes = {name: GonioAxis(link, name) for name in link.rig.axes}
    return GonioDevices(link, GonioCamera(link), axes, GonioPose(link))


def _end_sweep(link: RigLink) -> None:
    """A sweep still staged when the rig closes ends at a checkpoint (journaled)."""
    sweep, link.sweep = link.sweep, None
    if sweep is not None:
        link.worker.put(SweepRequest(sweep, END)).result()
