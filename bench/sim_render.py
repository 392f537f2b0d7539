"""The simulated camera's whole 24 MP image-based frame, against rawpy's bare decode of it.

``examples/rig-sphere-sim.toml`` with a 6000 × 4000 px sensor (:func:`image_session._rig_24mp`:
the 2 cm sphere fills 96 % of the image's height; 3000 × 2000 superpixels), its simulated
camera as a capture builds it (:func:`acquisition.simworld.camera.simulated_camera`, material
``image_session.MATERIAL``), the arms at the middle pose of ``image_session``'s plan (light and
camera 30° apart, the pose ``bench/image_reduce.py`` reduces). Interleaved, ``REPEATS`` times
after a warm-up (kernels compiled, page cache warm):

* the whole frame: :meth:`SimCamera.capture` — the scene (the compiled renderer,
  :mod:`acquisition.simworld.render_kernel`), the exposure (shot and read noise, ADC:
  :mod:`simulators.exposure`) and the DNG written and fsynced (:mod:`simulators.dng`);
* the bare decode of the DNG it wrote: ``rawpy.imread`` and ``raw_image_visible.copy()``,
  LibRaw's unpack and a copy out of its buffer (the least any reduction of it must do);
* the scene alone, and (``NUMPY_REPEATS`` times) the scene by the numpy path it replaced
  (:func:`acquisition.simworld.scene.render_image_numpy`, the compiled renderer's reference).

Figures (medians, wall time on a shared machine): ``sim_frame_24mp_s`` (the whole frame; goal
well under 1 s, issue 15), ``sim_frame_vs_decode`` (the whole frame's time / the bare decode's:
how many decodes one simulated frame costs), ``sim_scene_24mp_s``, ``sim_decode_24mp_s`` and
``sim_scene_vs_numpy`` (the numpy path's scene time / the compiled one's).
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rawpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import image_session  # noqa: E402  (the 24 MP rig and its poses)

REPEATS = 7
NUMPY_REPEATS = 3
EXPOSURE_S = 0.01
SEED = 7


def _decode(path: Path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        return raw.raw_image_visible.copy()


def _timed(call: object) -> float:
    t0 = time.perf_counter()
    call()  # type: ignore[operator]
    return time.perf_counter() - t0


def bench_sim_render() -> dict[str, dict[str, float | str]]:
    from acquisition.config.rig import load_rig
    from acquisition.simworld.camera import simulated_camera
    from acquisition.simworld.materials import parse_material
    from acquisition.simworld.misalignment import TrueGeometry
    from acquisition.simworld.scene import (
        SampleHolder,
        make_scene,
        render_image_numpy,
        white_material,
    )
    from simulators.clock import SteppedClock
    from simulators.rig_solids import KINDS

    with tempfile.TemporaryDirectory(prefix="gonio-bench-") as tmp:
        folder = Path(tmp)
        rig = load_rig(image_session._rig_24mp(folder))
        poses = image_session._phase_poses(image_session.PHASE_DEG)
        joints = KINDS[rig.kinematics_name].candidates(tuple(poses[len(poses) // 2]))[0]
        material = parse_material(image_session.MATERIAL)
        camera, _ = simulated_camera(rig, lambda: joints, material, SteppedClock(), SEED)
        dng = folder / "frame.dng"
        light, view = TrueGeometry(rig).directions(joints)
        shape = camera.sensor.superpixel_shape
        scene = make_scene(rig, lambda: joints, SampleHolder(material, white_material(rig)), shape)

        def frame() -> None:
            camera.capture(dng, EXPOSURE_S, frame_seed=1)

        frame(), _decode(dng), scene()  # warm the kernels and the page cache
        frame_s, decode_s, scene_s = [], [], []
        for _ in range(REPEATS):
            frame_s.append(_timed(frame))
            decode_s.append(_timed(lambda: _decode(dng)))
            scene_s.append(_timed(scene))
        numpy_s = [_timed(lambda: render_image_numpy(rig, view, material, shape, None,
                                                     light[None] * rig.light_distance_m))
                   for _ in range(NUMPY_REPEATS)]
    whole, decode, scene, numpy_scene = (statistics.median(x)
                                         for x in (frame_s, decode_s, scene_s, numpy_s))
    return {
        "sim_frame_24mp_s": {"value": whole, "unit": "s"},
        "sim_frame_vs_decode": {"value": whole / decode, "unit": "ratio"},
        "sim_scene_24mp_s": {"value": scene, "unit": "s"},
        "sim_decode_24mp_s": {"value": decode, "unit": "s"},
        "sim_scene_vs_numpy": {"value": numpy_scene / scene, "unit": "ratio"},
    }


if __name__ == "__main__":
    for key, fig in bench_sim_render().items():
        print(f"{key}: {fig['value']:.4g} {fig['unit']}")
