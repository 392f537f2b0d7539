"""Per-pixel geometry: pinhole camera, flat and spherical samples, point light, shading frames."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import acquisition.simworld.materials  # noqa: F401  (registers merl:PATH)
from acquisition.config.rig import SampleConfig, load_rig
from acquisition.formats.merl import write_merl
from acquisition.geometry.halfdiff import merl_bin_angles, vectors_from_halfdiff
from acquisition.reduction.imaging import (
    PinholeCamera,
    frame_geometry,
    intersect_sphere,
    pixel_geometry,
    tangent_frames,
)
from acquisition.simworld.scene import render_image
from drivers.errors import ConfigError
from simulators.materials import GGX, Lambert, material_from_spec

ROOT = Path(__file__).resolve().parent.parent
SPHERE_RIG = ROOT / "examples" / "rig-sphere-sim.toml"
SHAPE = (120, 160)
INTR = (400.0, 380.0, 79.5, 59.5)


def unit(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


@given(st.floats(0, 87), st.floats(-180, 180), st.floats(0.2, 2.0))
@settings(max_examples=60, deadline=None)
def test_rays_project_back_to_their_pixels(theta: float, phi: float, dist: float) -> None:
    cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(theta, phi), dist)
    rot = cam.rotation
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(rot), 1.0)
    x, y = cam.project(np.zeros(3))
    assert np.isclose(x, INTR[2]) and np.isclose(y, INTR[3])  # looks at the origin
    rays = cam.ray_directions()
    pts = cam.position + 0.7 * rays  # any point along a pixel's ray
    px, py = cam.project(pts)
    assert np.allclose(px, np.arange(SHAPE[1])[None, :], atol=1e-7)
    assert np.allclose(py, np.arange(SHAPE[0])[:, None], atol=1e-7)


@pytest.mark.parametrize("theta", [0.0, 30.0, 80.0])
def test_image_up_is_sample_z_and_minus_x_at_zenith(theta: float) -> None:
    cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(theta, 40.0), 0.6)
    up_point = np.array([-0.01, 0.0, 0.0]) if theta == 0 else np.array([0.0, 0.0, 0.01])
    x, y = cam.project(up_point)
    assert y < INTR[3] - 1 and abs(x - INTR[2]) < 1e-6  # straight up in the image
    if theta == 0:
        x, y = cam.project(np.array([0.0, 0.01, 0.0]))  # up = −x, so +y is to the right
        assert x > INTR[2] + 1 and abs(y - INTR[3]) < 1e-6


def test_flat_plate_geometry_matches_direct_formulas() -> None:
    sample = SampleConfig(shape="flat", size_m=0.04)
    cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(35.0, 120.0), 0.6)
    light = 0.5 * unit(50.0, -30.0)
    geo = pixel_geometry(cam, light, sample)
    # Independent construction: points of a grid on the plate, projected to pixels.
    rows, cols = np.nonzero(geo.mask)
    rays = cam.ray_directions()[rows, cols]
    t = -cam.position[2] / rays[:, 2]
    p = cam.position + t[:, None] * rays
    assert np.abs(p[:, :2]).max() <= 0.02 + 1e-12
    to_l = light - p
    r = np.linalg.norm(to_l, axis=1)
    assert np.allclose(geo.wi, to_l / r[:, None])
    assert np.allclose(geo.wo, (cam.position - p) / np.linalg.norm(cam.position - p, axis=1)[:, None])
    assert np.allclose(geo.irradiance, to_l[:, 2] / r**3)
    # The plate is a foreshortened square: about (0.04·f/0.6)² · cos 35° pixels.
    expected = (0.04 * 390 / 0.6) ** 2 * np.cos(np.radians(35))
    assert abs(geo.count / expected - 1) < 0.05
    # A pixel outside the plate's projection sees nothing.
    corner_x, corner_y = cam.project(np.array([0.03, 0.03, 0.0]))
    assert not geo.mask[int(round(float(corner_y))), int(round(float(corner_x)))]


def test_light_below_the_plate_lights_nothing() -> None:
    cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(20, 0), 0.6)
    geo = pixel_geometry(cam, np.array([0.0, 0.3, -0.1]), SampleConfig(size_m=0.04))
    assert geo.count == 0


def test_sphere_hits_lie_on_the_sphere_and_face_the_camera() -> None:
    centre = np.array([0.001, -0.002, 0.003])
    cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(60.0, 10.0), 0.5)
    hits = intersect_sphere(cam.position, cam.ray_directions(), 0.02, centre)
    assert np.allclose(np.linalg.norm(hits.points - centre, axis=1), 0.02)
    assert np.allclose(np.linalg.norm(hits.normals, axis=1), 1.0)
    view = cam.position - hits.points
    assert np.all(np.einsum("ij,ij->i", view, hits.normals) >= -1e-12)  # nearest side
    # Silhouette: a disk of radius f·r/√(d² − r²) pixels around the centre's projection.
    d = np.linalg.norm(cam.position - centre)
    radius_px = INTR[0] * 0.02 / np.sqrt(d**2 - 0.02**2)
    area = np.pi * radius_px * (INTR[1] / INTR[0]) * radius_px
    assert abs(hits.hit.sum() / area - 1) < 0.03


def test_sphere_mirror_pixel_has_half_vector_on_the_normal() -> None:
    sample = SampleConfig(shape="sphere", radius_m=0.02, image_based=True)
    cam_dir, light_dir = unit(45.0, 0.0), unit(30.0, 180.0)
    cam = PinholeCamera.looking_at_origin((2000.0, 2000.0, 79.5, 59.5), SHAPE, cam_dir, 3.0)
    geo = pixel_geometry(cam, 3.0 * light_dir, sample)
    h = geo.wi + geo.wo
    cos_h = h[:, 2] / np.linalg.norm(h, axis=1)
    # For a far light and camera the mirror point's normal is the bisector of the two.
    bis = (cam_dir + light_dir) / np.linalg.norm(cam_dir + light_dir)
    x, y = cam.project(0.02 * bis)
    rows, cols = np.nonzero(geo.mask)
    k = np.argmax(cos_h)
    assert abs(cols[k] - x) <= 1.5 and abs(rows[k] - y) <= 1.5
    pitch = 3.0 / (2000.0 * 0.02)  # normal change per pixel at the sphere's centre, rad
    assert cos_h[k] > np.cos(pitch * np.sqrt(0.5))
    # The lit, visible part: (1 + cos(light–camera angle)) / 2 of the disk.
    sep = np.arccos(cam_dir @ light_dir)
    disk = intersect_sphere(cam.position, cam.ray_directions(), 0.02, np.zeros(3)).hit.sum()
    assert abs(geo.count / disk - (1 + np.cos(sep)) / 2) < 0.03


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
def test_tangent_frames_are_right_handed_orthonormal(x: float, y: float, z: float) -> None:
    n = np.array([[x, y, z]])
    if np.linalg.norm(n) < 1e-3:
        return
    n = n / np.linalg.norm(n)
    t, b = tangent_frames(n)
    m = np.stack([t[0], b[0], n[0]])
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-9)
    assert np.allclose(np.cross(t[0], b[0]), n[0], atol=1e-9)


def test_local_angles_do_not_depend_on_the_sample_frame_azimuth() -> None:
    """Rotating light and camera together about the sphere's centre keeps every local
    (θi, θr, angle between) sample of the lit cap: only the tangent azimuth changes."""
    sample = SampleConfig(shape="sphere", radius_m=0.02, image_based=True)
    sig = []
    for phi in (0.0, 73.0):
        cam = PinholeCamera.looking_at_origin(INTR, SHAPE, unit(40.0, phi), 0.6)
        geo = pixel_geometry(cam, 0.5 * unit(20.0, phi + 180.0), sample)
        cos_io = np.einsum("ij,ij->i", geo.wi, geo.wo)
        sig.append(np.sort(np.round(geo.wi[:, 2] + 3 * geo.wo[:, 2] + 7 * cos_io, 6)))
    assert sig[0].size == sig[1].size and np.allclose(sig[0], sig[1], atol=1e-5)


def test_rig_without_intrinsics_is_refused_for_image_geometry() -> None:
    rig = load_rig(ROOT / "examples" / "rig-sim.toml")
    with pytest.raises(ConfigError, match="intrinsics"):
        frame_geometry(rig, unit(0, 0), unit(45, 0), (32, 48))


def test_one_sphere_frame_has_over_100k_pixel_samples() -> None:
    rig = load_rig(SPHERE_RIG)
    kin = rig.kinematics()
    g = kin.forward_geometry({"light_theta": 30.0, "camera_theta": 45.0, "camera_phi": 0.0})
    geo = frame_geometry(rig, g.light_dir, g.camera_dir, (500, 500))
    assert geo.count >= 100_000


def test_sphere_render_is_brdf_times_point_light_irradiance() -> None:
    rig = load_rig(SPHERE_RIG)
    light_dir, cam_dir = unit(30.0, 180.0), unit(45.0, 0.0)
    img = render_image(rig, light_dir, cam_dir, Lambert(0.5), (500, 500))
    geo = frame_geometry(rig, light_dir, cam_dir, (500, 500))
    assert np.count_nonzero(img[..., 0]) == geo.count
    # At the sphere's top the normal is +z: L = ρ/π · I · cos θi / r² with the light 0.48 m off.
    x, y = PinholeCamera.looking_at_origin(
        (7200.0, 7200.0, 249.5, 249.5), (500, 500), cam_dir, rig.camera_distance_m
    ).project(np.array([0.0, 0.0, 0.02]))
    top = np.array([0.0, 0.0, 0.02])
    to_l = rig.light_distance_m * light_dir - top
    r = np.linalg.norm(to_l)
    expected = 0.5 / np.pi * rig.light_intensity_w_per_sr * (to_l[2] / r) / r**2
    value = img[int(round(float(y))), int(round(float(x))), 1]
    assert value == pytest.approx(expected, rel=0.01)


def test_merl_material_renders_per_pixel(tmp_path: Path) -> None:
    """A ``merl:PATH`` material goes through the per-pixel path: each pixel is the MERL
    lookup at its own (wi, wo), and the file tabulated from a GGX renders like the GGX."""
    ggx = GGX(0.3, 0.3, 0.1)
    th, td, pd = np.meshgrid(*merl_bin_angles(), indexing="ij")
    values = ggx.eval_vectors(*vectors_from_halfdiff(th, td, pd))
    path = tmp_path / "ggx.binary"
    write_merl(path, values)
    merl = material_from_spec(f"merl:{path}")
    rig = dataclasses.replace(load_rig(SPHERE_RIG))
    light_dir, cam_dir = unit(20.0, 180.0), unit(45.0, 0.0)
    shape = (250, 250)
    rig = dataclasses.replace(
        rig, camera=dataclasses.replace(rig.camera, intrinsics=dataclasses.replace(
            rig.camera.intrinsics, fx=3600.0, fy=3600.0)))
    img = render_image(rig, light_dir, cam_dir, merl, shape)
    geo = frame_geometry(rig, light_dir, cam_dir, shape)
    direct = merl.eval_vectors(geo.wi, geo.wo) * (rig.light_intensity_w_per_sr * geo.irradiance)[:, None]
    assert np.allclose(img[geo.mask], direct)
    ref = render_image(rig, light_dir, cam_dir, ggx, shape)[geo.mask]
    rel = np.abs(img[geo.mask] - ref) / ref
    assert np.median(rel) < 0.03  # nearest-bin lookup of a tabulated GGX
