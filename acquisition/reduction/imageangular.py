"""Angular uncertainty of an image-based reduction, per frame and bin.

The terms are the point reduction's, computed by the same functions
(:mod:`acquisition.reduction.angular`): ``angular`` (the arms' position noise),
``geometry_calibration`` (the calibration's 1σ: zero offsets, sample tilt, backlash and, on an
image-based rig, the camera's pointing), ``backlash`` (the correction for a stated backlash)
and ``source_size`` (the lamp's disc). Three things differ from a point reduction's.

**A frame's pixels err together.** The arms stand in one pose per frame, so a joint error
moves the geometry of every pixel of that frame at once (and the calibration's error that of
every pixel of every frame). Within a bin, the pixels one frame puts there (a *frame-bin*)
share their error: it adds linearly over them and does not average down as 1/√n; frames, each
its own draw of the joint errors, add in quadrature (a rig stating backlash approaches every
target afresh; an arm that stays put between two frames keeps its error, which the budget does
not follow). So a bin's ``angular`` term is
√(Σₖ nₖ² varₖ) / n — varₖ the variance of frame-bin k's mean value, nₖ its pixels, n the
bin's — where counting the pixels as independent would make it up to √nₖ times smaller. The
calibration's and the stated backlash's terms add linearly over the bin's frame-bins,
u = Σₖ nₖ uₖ / n (the table's rule for a correlated term), and so does the lamp correction's
(one model corrects all of them).
Between bins a frame's error is shared too; the budget knows only independent and fully
correlated terms, so ``angular`` is stored as independent between bins (as in the point
reduction, where every sample is its own frame): a fit taking it so weighs each bin right but
counts one frame's error once per bin it reaches.

**The BRDF's slope from each frame itself, in half/difference coordinates.** A frame of a
sphere is a two-dimensional slice of the BRDF at one light–camera angle (θd ≈ half of it), and
a joint error moves its pixels off that slice. In (θi, θr, Δφ) neighbouring slices lie where a
specular peak has moved on, so a local fit there mixes the peak's flanks (its slopes came out
up to 25 times too steep). In the coordinates (θh cos φd, θh sin φd, θd) (MERL's, Cartesian
about the specular direction, so smooth through it) the peak stays put from slice to slice:
the local quadratic model of ln f is fitted within the frame's slice, in the first two, over
its frame-bins and their mirror images (isotropy and reciprocity make f even in both;
:func:`~acquisition.reduction.angular.local_models`), and the slow θd dependence across slices
(Fresnel, masking, the projected area: about 2 tan θd per radian at the peak, under a tenth of
the slopes within the slice there) is left out. A frame-bin's mean is the BRDF averaged over
its pixels' footprint; moving or blurring the footprint changes it by the footprint's average
of ∇f and of ½ tr(Σ ∇²f), the derivatives of the averaged BRDF the fit sees. The measured value
divides by the assumed irradiance, so θi is a fourth coordinate
(:func:`~acquisition.reduction.angular.with_irradiance`).

**Jacobians through the pixels' own geometry.** Each frame-bin's coordinates and their
Jacobians — with respect to the joints, to the calibration's parameters and to the lamp's
position across its disc — are those of its pixel nearest its centroid in the image, by
central differences through the reduction's per-pixel geometry
(:func:`~acquisition.reduction.imaging.frame_geometry` at those pixels only): smooth across the
footprint in raw coordinates. The model, fitted in folded ones (|θh cos φd|, |θh sin φd|), is
unfolded by the mean signs of the frame-bin's pixels (and of their products, for the
curvature): mirror pixels on either side of the plane of incidence err in opposite senses, and
their errors cancel in the mean as they do in the model.

The lamp's blur is corrected in each bin's mean (by its frame-bins' value-weighted bias; the
MERL table keeps the pixels' values as measured).

Cost: per frame, grouping its pixels by bin (a sort) and 2 (J + P + 2) geometry evaluations at
one pixel per frame-bin (J joints, P calibration parameters); per reduction, one local fit per
frame-bin.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.geometry.alignment import POINTING_PARAMS
from acquisition.geometry.halfdiff import halfdiff_from_vectors
from acquisition.geometry.kinematics import Kinematics
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.reduction.angular import (
    ANGULAR_TERM,
    BACKLASH_TERM,
    CALIBRATION_TERM,
    RAD,
    SOURCE_CORRECTION_FRACTION,
    SOURCE_TERM,
    AngularSources,
    AngularTerms,
    central_difference,
    local_models,
    terms_at,
    with_irradiance,
)
from acquisition.reduction.imaging import Pixels, frame_geometry
from acquisition.reduction.pose_kernels import sample_poses
from acquisition.reduction.samplegeometry import SampleGeometry
from acquisition.tables import IsotropicTable

FRAME_NOTE = "; a frame's pixels together (one pose of the arms)"
"""Appended to the image-based budget's angular terms' descriptions."""
DEGENERATE_THETA_D_DEG = 1.0
"""Below this θd (light and camera nearly together) φd is undefined: its row is 0."""


@dataclass(frozen=True)
class FrameBins:
    """One frame's pixels grouped by the bin they fall in (K frame-bins), with their terms."""

    bins: np.ndarray
    """(K,) flat bin index."""
    count: np.ndarray
    """(K,) pixels."""
    value: np.ndarray
    """(K, 3) their mean value, sr⁻¹."""
    terms: AngularTerms
    """The frame-bins' angular terms (of their mean values)."""

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The frame-bins as named arrays (a partial table's frame data)."""
        t = self.terms
        return {"bins": self.bins, "count": self.count, "value": self.value,
                "variance": t.variance, "calibration": t.calibration,
                "source_bias": t.source_bias, "backlash": t.backlash}

    @classmethod
    def from_arrays(cls, a: Mapping[str, np.ndarray]) -> FrameBins:
        """Inverse of :meth:`to_arrays`."""
        return cls(np.asarray(a["bins"]), np.asarray(a["count"]), np.asarray(a["value"]),
                   AngularTerms(np.asarray(a["variance"]), np.asarray(a["calibration"]),
                                np.asarray(a["source_bias"]), np.asarray(a["backlash"])))

    @classmethod
    def concatenate(cls, parts: list[FrameBins]) -> FrameBins:
        def cat(get: Callable[[FrameBins], np.ndarray]) -> np.ndarray:
            return np.concatenate([get(p) for p in parts])

        return cls(cat(lambda p: p.bins), cat(lambda p: p.count), cat(lambda p: p.value),
                   AngularTerms(cat(lambda p: p.terms.variance),
                                cat(lambda p: p.terms.calibration),
                                cat(lambda p: p.terms.source_bias),
                                cat(lambda p: p.terms.backlash)))


def smooth_coordinates(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """(θh cos φd, θh sin φd, θd, θi) in degrees (K, 4) of local unit directions (K, 3)."""
    th, td, pd = halfdiff_from_vectors(wi, wo)
    pd = np.radians(pd)
    theta_i = np.degrees(np.arccos(np.clip(wi[:, 2], -1.0, 1.0)))
    return np.column_stack([th * np.cos(pd), th * np.sin(pd), td, theta_i])


class ImageAngular:
    """Collects every frame's frame-bins, then puts the angular terms into the table."""

    def __init__(self, rig: RigConfig, model: SampleGeometry, table: IsotropicTable) -> None:
        self.rig, self.model, self.table = rig, model, table
        self.sources = AngularSources.of(rig, model)
        self._frames: list[FrameBins] = []

    @property
    def active(self) -> bool:
        """Whether the rig states any angular error (else the budget has no angular term)."""
        s = self.sources
        return s.joints_needed or s.correlated or s.source

    def add(self, joints: Mapping[str, float], shape: tuple[int, int], pixels: Pixels,
            wi: np.ndarray, wo: np.ndarray, values: np.ndarray) -> None:
        """One frame (see :meth:`frame_bins`), kept for :meth:`apply`."""
        fb = self.frame_bins(joints, shape, pixels, wi, wo, values)
        if fb is not None:
            self._frames.append(fb)

    def frame_bins(self, joints: Mapping[str, float], shape: tuple[int, int], pixels: Pixels,
                   wi: np.ndarray, wo: np.ndarray, values: np.ndarray) -> FrameBins | None:
        """One frame's frame-bins and their terms, from its read-back joints, image shape
        (superpixels), and its samples' pixels (rows, columns), local directions (N, 3) and
        values (N, 3); None when the rig states no angular error or no pixel is binned."""
        if not self.active:
            return None
        group = _FrameGroups.of(self.table, pixels, wi, wo, values)
        if group is None:
            return None
        at = _PixelCoordinates(self.rig, self.model, joints, shape, group.central)
        raw = at.coords()
        s = self.sources
        grad, hess = _models(np.nan_to_num(np.column_stack([np.abs(raw[:, :2]), raw[:, 2:]])),
                             group.value)
        sign, product = group.sign_means(raw[:, 2] >= DEGENERATE_THETA_D_DEG)
        grad, hess = grad * sign[:, None, :], hess * product[:, None, :, :]
        disc = None
        if s.source:
            dj = np.nan_to_num(at.disc_jacobians())
            disc = np.einsum("kil,kjl->kij", dj, dj) * s.source_radius_deg**2 / 4.0
        terms = terms_at(
            s, grad, hess, group.value,
            np.nan_to_num(at.joint_jacobians()) if s.joints_needed else None,
            np.nan_to_num(at.calibration_jacobians(s.calibration_names)) if s.correlated
            else None, disc)
        return FrameBins(group.bins, group.count, group.value, terms)

    def terms(self) -> tuple[dict[str, str], dict[str, str]]:
        """(independent, correlated) names → descriptions of the terms :meth:`apply` adds."""
        s = self.sources
        independent = {k: v + FRAME_NOTE for k, v in ANGULAR_TERM.items()} if s.independent else {}
        if s.source:
            independent.update({k: v + "; one correction per bin" for k, v in SOURCE_TERM.items()})
        correlated = {k: v + FRAME_NOTE for k, v in CALIBRATION_TERM.items()} if s.correlated else {}
        if s.stated_backlash:
            correlated.update({k: v + FRAME_NOTE for k, v in BACKLASH_TERM.items()})
        return independent, correlated

    def apply(self, frames: list[FrameBins] | None = None) -> None:
        """Add the terms of ``frames`` (default: those :meth:`add` kept; in frame order, so
        that the sums are the same however the frames were reduced) to the table's budget and
        correct its means for the lamp's blur (module docstring); call once every frame is
        binned."""
        frames = self._frames if frames is None else frames
        if not frames:
            return
        fb, t = FrameBins.concatenate(frames), self.table
        terms = fb.terms
        n = t.count.reshape(-1).astype(float)[:, None]
        k = fb.count.astype(float)[:, None]

        def total(x: np.ndarray) -> np.ndarray:
            """Σ over each bin's frame-bins of x (K, 3): (bins, 3)."""
            return np.column_stack([np.bincount(fb.bins, x[:, c], len(n)) for c in range(3)])

        def binned(x: np.ndarray) -> np.ndarray:
            return x.reshape(*t.shape, 3)

        independent, correlated = self.terms()
        with np.errstate(invalid="ignore", divide="ignore"):
            for name, description in independent.items():
                if name in ANGULAR_TERM:
                    u = np.sqrt(total(k**2 * terms.variance)) / n
                else:  # the lamp: the bin's mean corrected, a fraction of it its uncertainty
                    corrected = fb.value / (1.0 + terms.source_bias)
                    u = np.abs(total(k * SOURCE_CORRECTION_FRACTION * terms.source_bias
                                     * corrected)) / n
                    t.scale_bins(binned(total(k * corrected) / total(k * fb.value)))
                t.set_bin_term(name, description, binned(u))
            for name, description in correlated.items():
                u = terms.backlash if name in BACKLASH_TERM else terms.calibration
                t.set_bin_term(name, description, binned(total(k * u) / n), correlated=True)


@dataclass(frozen=True)
class _FrameGroups:
    """A frame's pixels grouped by bin (:meth:`of`): each group's bin, pixel count, mean
    value, central pixel (nearest its centroid in the image) and the mean signs of its pixels'
    (θh cos φd, θh sin φd), and of their product."""

    bins: np.ndarray
    count: np.ndarray
    value: np.ndarray
    central: Pixels
    sign: np.ndarray
    """(K, 2) mean signs."""
    product: np.ndarray
    """(K,) mean sign product."""

    @classmethod
    def of(cls, table: IsotropicTable, pixels: Pixels, wi: np.ndarray, wo: np.ndarray,
           values: np.ndarray) -> _FrameGroups | None:
        angles = sample_poses(wi, wo)  # the bins bin_frames puts these samples in
        flat = table.flat_index(angles[:, 0], angles[:, 1], angles[:, 2])
        keep = (flat >= 0) & np.all(np.isfinite(values), axis=1)
        if not keep.any():
            return None
        bins, inv, count = np.unique(flat[keep], return_inverse=True, return_counts=True)

        def mean(x: np.ndarray) -> np.ndarray:
            return np.column_stack([np.bincount(inv, x[:, c], len(bins)) for c in
                                    range(x.shape[1])]) / count[:, None]

        rc = np.column_stack([pixels[0][keep], pixels[1][keep]])
        d2 = np.sum((rc - mean(rc.astype(float))[inv]) ** 2, axis=1)
        central = np.lexsort((d2, inv))[np.concatenate([[0], np.cumsum(count)[:-1]])]
        phi_d = np.radians(halfdiff_from_vectors(wi[keep], wo[keep])[2])
        signs = np.column_stack([np.where(np.cos(phi_d) < 0, -1.0, 1.0),
                                 np.where(np.sin(phi_d) < 0, -1.0, 1.0)])
        return cls(bins, count, mean(values[keep]), (rc[central, 0], rc[central, 1]),
                   mean(signs), mean(signs[:, :1] * signs[:, 1:])[:, 0])

    def sign_means(self, defined: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mean over each group's pixels of s (K, 4) and of s sᵀ (K, 4, 4), s the signs of
        their coordinates (1 for θd and θi; 0 for the first two where φd is not ``defined``):
        a local model of the folded coordinates, times them, is the groups' mean model in
        raw coordinates (its Jacobians are the central pixel's, smooth across a group)."""
        m = np.ones((len(self.bins), 4))
        m[:, :2] = self.sign * defined[:, None]
        out = m[:, :, None] * m[:, None, :]
        out[:, 0, 0] = out[:, 1, 1] = defined
        out[:, 0, 1] = out[:, 1, 0] = self.product * defined
        return m, out


def _models(coords: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The local model of the measured value's logarithm at each of a frame's frame-bins
    (gradient (K, 3, 4), Hessian (K, 3, 4, 4) in the coordinates (K, 4)): ln f within the
    frame's slice, over its frame-bins and their mirror images, in the first two; none across
    slices (the third); the assumed irradiance in the fourth."""
    centres = coords[:, :2]
    log_f = np.log(np.maximum(np.abs(values), 1e-300))
    mirrors = [centres * [sx, sy] for sx in (1.0, -1.0) for sy in (1.0, -1.0)]
    g2, h2 = local_models(centres, np.ones(len(centres)), np.vstack(mirrors),
                          np.vstack([log_f] * len(mirrors)))
    grad = np.zeros((*g2.shape[:2], 4))
    hess = np.zeros((*h2.shape[:2], 4, 4))
    grad[..., :2], hess[..., :2, :2] = g2, h2
    return with_irradiance(grad, hess, coords[:, 3], axis=3)


@dataclass(frozen=True)
class _PixelCoordinates:
    """The :func:`smooth_coordinates` of some pixels of a frame as the reduction's geometry
    gives them, and their Jacobians."""

    rig: RigConfig
    model: SampleGeometry
    joints: Mapping[str, float]
    shape: tuple[int, int]
    pixels: Pixels

    def coords(self, kin: Kinematics | None = None, joints: np.ndarray | None = None,
               pointing_deg: tuple[float, float] | None = None,
               light_turn_deg: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """(K, 4) coordinates of the pixels with the arms at ``joints`` (J,) through ``kin``
        (default: the frame's), the camera's pointing, and the light turned across its disc;
        NaN where a pixel no longer sees the lit sample."""
        kin = kin or self.model.kinematics
        j = self._joints if joints is None else joints
        light, camera = (v[0] for v in kin.forward_array(j[None]))
        u, v = _across(light)
        turned = light + np.tan(light_turn_deg[0] * RAD) * u + np.tan(light_turn_deg[1] * RAD) * v
        geo = frame_geometry(self.rig, light, camera, self.shape,
                             pointing_deg=pointing_deg or self.model.pointing_deg,
                             light_pos=turned / np.linalg.norm(turned) * self.rig.light_distance_m,
                             pixels=self.pixels)
        out = np.full((len(self.pixels[0]), 4), np.nan)
        out[geo.mask] = smooth_coordinates(geo.wi, geo.wo)
        return out

    @property
    def _joints(self) -> np.ndarray:
        return self.model.kinematics.to_array(self.joints)

    @staticmethod
    def _jacobian(moved: list[Callable[[float], np.ndarray]]) -> np.ndarray:
        """(K, 4, M) from M functions step (deg) → coordinates (K, 4) (the wrap
        :func:`~acquisition.reduction.angular.central_difference` applies to a Δφ leaves the
        small change of θd as it is)."""
        return np.stack([central_difference(f) for f in moved], axis=2)

    def joint_jacobians(self) -> np.ndarray:
        """(K, 4, J) d coordinates / d joint."""
        j0 = self._joints
        return self._jacobian([lambda step, j=j: self.coords(joints=j0 + step * np.eye(len(j0))[j])
                               for j in range(len(j0))])

    def calibration_jacobians(self, names: tuple[str, ...]) -> np.ndarray:
        """(K, 4, P) d coordinates / d calibration parameter ``names`` (the alignment's, then
        the camera pointing's)."""
        model = self.model
        corrections = model.corrections
        assert corrections is not None

        def moved(name: str) -> Callable[[float], np.ndarray]:
            if name in POINTING_PARAMS:
                axis = np.eye(2)[POINTING_PARAMS.index(name)]
                return lambda step: self.coords(pointing_deg=tuple(  # type: ignore[arg-type]
                    np.asarray(model.pointing_deg) + step * axis))
            return lambda step: self.coords(
                CalibratedKinematics(model.base, corrections.shifted(name, step)))

        return self._jacobian([moved(n) for n in names])

    def disc_jacobians(self) -> np.ndarray:
        """(K, 4, 2) d coordinates / d the light's direction turned across two axes (deg)."""
        return self._jacobian([lambda step, a=a: self.coords(
            light_turn_deg=(step, 0.0) if a == 0 else (0.0, step)) for a in (0, 1)])


def _across(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``direction`` and to each other."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(direction, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(direction, u)
