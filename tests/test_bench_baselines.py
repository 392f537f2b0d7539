"""The benchmarks' own baselines: the DMX wire latency computed from DMX512 agrees with the
simulated widget's timing model, and the image-session plan keeps one light–camera angle."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from simulators.dmx import SimDmxWidget

BENCH = Path(__file__).resolve().parent.parent / "bench"


def _bench(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


@pytest.mark.parametrize("channels", [1, 24, 156, 512])
def test_dmx_wire_time_matches_the_simulated_widget(channels: int) -> None:
    dmx = _bench("dmx")
    widget = SimDmxWidget(break_units=dmx.BREAK_UNITS, mab_units=dmx.MAB_UNITS,
                          refresh_rate_hz=dmx.OUTPUT_RATE_HZ)  # never started: no pty
    assert dmx.wire_frame_s(channels) == pytest.approx(widget.sim_frame_time_s(channels))
    assert dmx.wire_latency_s(channels) == pytest.approx(
        widget.sim_frame_period_s(channels) + widget.sim_frame_time_s(channels))


def test_dmx_docstring_figures() -> None:
    dmx = _bench("dmx")
    assert dmx.wire_frame_s(156) * 1e3 == pytest.approx(7.01, abs=0.005)
    assert dmx.wire_latency_s(156) * 1e3 == pytest.approx(32.0, abs=0.05)


def _direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def test_image_session_poses_keep_one_phase_angle() -> None:
    session = _bench("image_session")
    poses = session._phase_poses(session.PHASE_DEG)
    assert len(poses) >= 2 * session.FRAMES
    assert {p[2] for p in poses} >= {0.0, 90.0, 180.0}  # the arms go all over
    for ti, tr, dphi in poses:
        cos = _direction(ti, 0.0) @ _direction(tr, dphi)
        assert math.degrees(math.acos(min(cos, 1.0))) == pytest.approx(session.PHASE_DEG, abs=1e-3)


def test_per_pixel_floor_does_the_paths_arithmetic() -> None:
    """bench/_per_pixel_floor.py (image_per_pixel_floor_msamples_per_s) computes what the
    per-pixel path adds: on a frame with every pixel valid, its candidates are
    pixel_samples' samples and its 21 column totals those of their values."""
    from test_imaging_kernels import scene

    from acquisition.reduction.imaging import frame_parameters, pixel_samples
    from acquisition.reduction.pose_kernels import sample_poses
    from acquisition.reduction.sample_kernels import column_x
    from acquisition.reduction.sample_spans import row_spans

    floor = _bench("_per_pixel_floor")
    cam, light, sample = scene(15, 30.0, 40.0, "sphere")
    h, w = (int(s) for s in cam.shape)
    rng = np.random.default_rng(3)
    rgb = rng.uniform(1.0, 5e4, (h, w, 3)).astype(np.float32)
    var = rng.uniform(1.0, 1e3, (h, w, 3)).astype(np.float32)
    cal, rel = rng.uniform(1e-3, 1e3, 3), np.array([0.01, 0.02, 0.03])
    wi, wo, brdf, variance, _ = pixel_samples(cam, light, sample, rgb, np.ones((h, w), bool),
                                              var, cal, 0.02)
    p = frame_parameters(cam, light, sample)
    acc = np.zeros((3, floor.SUMS))
    n = floor.floor_rows((p, column_x(p, w), 0.02), row_spans(p, (h, w)), 0, h,
                         rgb.reshape(h, 3 * w), var.reshape(h, 3 * w), cal, rel, acc)
    assert n == wi.shape[0] > 2000
    ti, tr, dp = sample_poses(wi, wo).T
    columns = [*brdf.T, *(brdf**2).T, *variance.T, *(np.abs(brdf) * rel).T, ti, tr, dp,
               ti * ti, tr * tr, dp * dp, ti * tr, ti * dp, tr * dp]
    got = acc.sum(axis=0)
    for q, column in enumerate(columns):
        assert got[q] == pytest.approx(math.fsum(column), rel=1e-12), q
