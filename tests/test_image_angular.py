"""The image-based reduction's angular terms (issue 14) on a sphere rig whose arms do not stand
quite where their ticks say: every bin's predicted uncertainty, the ``angular`` term included,
matches its error against the truth; the calibration's uncertainty, the camera's pointing
included, is a correlated term of the size its parameters' 1σ makes.

The capture is uncalibrated, with position noise (0.05° per axis, drawn anew every move) and a
5 mm lamp: ``gonio calibrate geometry`` does run on an image-based rig, but its ``geometry_
calibration`` term is there one common error of every bin, ten times the rest (a camera pointing
error moves the normal a pixel sees by camera distance / sphere radius = 30 times as much), so a
spread over bins measures a single draw of it; its size is checked against the reduction's own
response to one parameter moved by its 1σ instead."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from misaligned import sphere_rig

from acquisition import api
from acquisition.api.truth import image_truth_table
from acquisition.geometry.alignment import Alignment
from acquisition.reduction.image import ImageReducer, reduce_image_session
from acquisition.tables import IsotropicTable
from acquisition.tables.partial import load_partial, merge_all, save_partial
from calibration.bundle import CalibrationBundle

MATERIAL = "ggx:albedo=0.1,alpha=0.1,f0=0.5"
ERRORS = """position_noise_deg = { light_theta = 0.05, camera_theta = 0.05, camera_phi = 0.05 }
source_diameter_m = 0.005
seed = 1"""
POSES = [[20 + 1.5 * k, 25 + 0.9 * (7 * k % 24), 169 + 0.9 * (5 * k % 24)] for k in range(24)]
"""24 frames, every axis moving between any two (an arm that stays put keeps its position
error: frames sharing it would make fewer independent draws), light–camera angles 45–100°
(the frames' specular peaks all above half the highest one)."""
POINTING_SIGMA_DEG = 0.005


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """rig-sphere-sim.toml at 0.3× the resolution (the sphere 72 superpixels in radius) with
    the errors above, the GGX material captured over :data:`POSES` into 2° bins."""
    root = tmp_path_factory.mktemp("image-angular")
    sphere_rig(root, 0.3, ERRORS)
    rows = ", ".join(f"[{a:g}, {b:g}, {c:g}]" for a, b, c in POSES)
    (root / "plan.toml").write_text(
        f'format_version = 1\nname = "sphere-peaks"\n[sampling]\nkind = "list"\n'
        f'reciprocal = "both"\nbin_deg = 2\nposes = [{rows}]\n')
    api.capture(root / "rig.toml", root / "plan.toml", root / "s", material=MATERIAL, seed=5)
    return root / "s"


def _peak(table: IsotropicTable, truth: IsotropicTable) -> np.ndarray:
    green = truth.mean[..., 1]
    return (table.count > 0) & (truth.count > 0) & (green >= 0.5 * np.nanmax(green))


def test_predicted_uncertainty_matches_the_error_on_the_peak(session: Path) -> None:
    table = reduce_image_session(session).table
    truth = image_truth_table(session)
    peak = _peak(table, truth)
    terms = table.uncertainty_terms
    assert {"angular", "source_size"} <= set(terms) and "geometry_calibration" not in terms
    assert not terms["angular"].correlated and not terms["source_size"].correlated
    # The truth is the material at the very pixels of each bin: where they fell in the bin
    # (the binning term) is no error against it.
    measured = np.sqrt(sum(t.values**2 for k, t in terms.items() if k != "binning"))
    z = ((table.mean - truth.mean) / measured)[..., 1][peak]
    with_binning = ((table.mean - truth.mean) / table.std_error)[..., 1][peak]
    median = {k: float(np.median(t.values[..., 1][peak] / table.mean[..., 1][peak]))
              for k, t in terms.items()}
    print(f"{z.size} peak bins: error / uncertainty std {np.std(z):.3f} (with the binning term "
          f"{np.std(with_binning):.3f}); medians " + ", ".join(f"{k} {v:.2%}" for k, v in
                                                                median.items()))
    assert z.size >= 100
    assert 0.7 <= float(np.std(z)) <= 1.3
    assert median["angular"] > 2 * median["noise"]  # the spread tests the angular term


def test_the_calibration_and_its_pointing_are_a_correlated_term(session: Path,
                                                                 tmp_path: Path) -> None:
    """A calibration whose only uncertainty is the camera pointing's (1σ 0.005° about the
    image's y), off by just that: each peak bin's error is the size of its
    ``geometry_calibration`` term (the other terms are a tenth of it)."""
    a = Alignment(camera_pointing_deg=(0.0, POINTING_SIGMA_DEG),
                  camera_pointing_sigma_deg=(0.0, POINTING_SIGMA_DEG))
    CalibrationBundle.create(tmp_path / "cal").set_geometry(a.to_dict(), {"procedure": "by hand"})
    table = reduce_image_session(session, bundle=tmp_path / "cal").table
    truth = image_truth_table(session, bundle=tmp_path / "cal")
    term = table.uncertainty_terms["geometry_calibration"]
    assert term.correlated and table.provenance["geometry_calibration"]
    peak = _peak(table, truth)
    u = term.values[..., 1][peak]
    assert np.all(u > 0)
    ratio = np.abs(table.mean - truth.mean)[..., 1][peak] / u
    print(f"{ratio.size} peak bins: |error| / geometry_calibration median {np.median(ratio):.3f}"
          f" (quartiles {np.percentile(ratio, 25):.3f}–{np.percentile(ratio, 75):.3f}); the "
          f"term's median {np.median(u / table.mean[..., 1][peak]):.2%}")
    assert ratio.size >= 100
    assert 0.7 <= float(np.median(ratio)) <= 1.3


def test_angular_terms_survive_any_split_into_partials(session: Path, tmp_path: Path) -> None:
    """The angular terms come from each frame's frame-bins, carried in the partial tables:
    frames reduced in any split and order, one partial through a file, merged, finish into
    the table a sequential reduction gives, budget and lamp correction included, bit for bit."""
    whole = reduce_image_session(session).table
    assert {"angular", "source_size"} <= set(whole.uncertainty_terms)
    reducer = ImageReducer.open(session)
    order = np.random.default_rng(3).permutation(len(reducer.frames))
    parts = [reducer.partial([reducer.frames[i] for i in chunk])
             for chunk in np.array_split(order, 3)]
    assert all(p.frame_data for p in parts)
    parts[0] = load_partial(save_partial(tmp_path / "part.h5", parts[0]))
    table = reducer.reduction(merge_all(parts[::-1])).table
    assert table.uncertainty_terms.keys() == whole.uncertainty_terms.keys()
    for name, term in whole.uncertainty_terms.items():
        np.testing.assert_array_equal(table.uncertainty_terms[name].values, term.values, name)
    np.testing.assert_array_equal(table.mean, whole.mean)
    np.testing.assert_array_equal(table.std_error, whole.std_error)
