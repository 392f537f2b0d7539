"""Angular uncertainty of every sample: where the arms really were, through the BRDF's slope.

A sample's value belongs to the pose the reduction's geometry model gives its read-back joints
(:class:`~acquisition.reduction.samplegeometry.SampleGeometry`: the rig file's, corrected by
the geometric calibration when one is applied and by the backlash the rig file states). The
arms stood a little elsewhere:

* independent per sample — each axis' position noise (σ) as the rig file states it
  (``[axes.NAME] position_noise_deg``; a rig with backlash approaches every target afresh, so
  each step draws it anew);
* common to every sample — the geometric calibration's own error (its covariance of zero
  offsets, tilt and backlash), and the error of the correction for a backlash the rig file
  states (``backlash_deg``, axes no calibration measured). A rig stating backlash approaches
  every target from one side (:mod:`acquisition.geometry.approach`: from below unless the
  lower limit leaves no room), so each arm stands ``b/2`` behind its commanded angle on the
  side :func:`~acquisition.geometry.approach.approach_signs` gives, every frame approached
  from that side alike: a systematic offset, not a ±b/2 drawn anew per sample (the simulated
  gears, :mod:`simulators.dynamixel.drivetrain`, do the same). So the reduction corrects it,
  as it corrects a backlash the calibration measured, and budgets what is left — the stated b
  known to :data:`BACKLASH_CORRECTION_FRACTION` of itself (a datasheet's figure or a one-off
  measurement; ``gonio calibrate geometry`` measures it) — as the correlated term
  ``backlash`` (:data:`BACKLASH_TERM`). Budgeting ±b/2 as independent would leave a known bias
  in every value and claim that it averages down over samples and bins, which it does not
  (tests/test_backlash_budget.py: with 0.2° of backlash and no other error, an uncalibrated
  GGX capture's peak bins so corrected err as their noise predicts — spread 1.01 — and the
  term is the size of the truth's change when an axis' b moves by its 1σ — ratio 1.10 —
  where uncorrected they are 2.8 % off, 100 times their noise);
* the lamp's size (``[light] source_diameter_m``): a value is the BRDF averaged over the
  directions of a disc, not its value at the disc's centre — a bias of
  ½ tr(H Σ) + ½ Gᵀ Σ G (Σ: the disc's direction covariance, ρ²/4 in each of its two
  directions; negative at a peak, where the curvature is). The reduction corrects it and
  budgets :data:`SOURCE_CORRECTION_FRACTION` of the correction as its uncertainty (the
  curvature is the measurement's own, itself blurred and sampled).

Each joint error moves the pose by the kinematics' Jacobian (:func:`pose_jacobians`), and the
measured value by the BRDF's relative change there, times cos θi_true / cos θi (the
irradiance the reduction divides by: :func:`with_irradiance`). The BRDF's local variation
comes from the measurement itself: a weighted quadratic fit of ln f over each sample's
neighbours (:func:`local_log_models`; reciprocity and Δφ ↔ −Δφ supply neighbours on every
side). Where the first-order term Gᵀ Σ G is adequate it is used; near an extremum (a peak,
where the gradient vanishes and the curvature rules: second-order terms above
:data:`NONLINEAR_FRACTION` of it) the independent term is a Monte Carlo over :data:`MC_DRAWS`
fixed draws of the joint errors (GUM Supplement 1), the correlated one the second-order closed
form for Gaussian errors. Both are returned as relative variances of the sample's value.

:func:`terms_at` computes the terms in any coordinates the local model and the Jacobians share
(the point reduction's (θi, θr, |Δφ|); the image-based reduction's half/difference ones,
:mod:`acquisition.reduction.imageangular`), and :func:`local_models` fits in any of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.geometry.alignment import POINTING_PARAMS, Alignment
from acquisition.geometry.kinematics import Kinematics
from acquisition.geometry.kinematics.base import wrap_deg_array
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.reduction.samplegeometry import SampleGeometry

ANGULAR_TERM = {"angular": "the arms' position noise (rig file) through the BRDF's local "
                           "slope and curvature, independent"}
CALIBRATION_TERM = {"geometry_calibration": "the geometric calibration's 1σ (zero offsets, "
                                            "sample tilt, backlash) through the BRDF's local "
                                            "slope, common to the bins"}
SOURCE_TERM = {"source_size": "the correction for the lamp's disc (rig file's [light] "
                              "source_diameter_m) blurring the BRDF by its local curvature, "
                              "independent"}
SOURCE_CORRECTION_FRACTION = 0.3
"""Standard uncertainty of the source-size correction, as a fraction of it."""
BACKLASH_CORRECTION_FRACTION = 0.3
"""Standard uncertainty of a stated backlash (and of the correction for it), as a fraction of
it: a stated play is a specification or a one-off measurement, not this rig's calibration."""
BACKLASH_TERM = {"backlash": "the correction for the backlash the rig file states (each arm "
                             "b/2 behind the side it approached from) through the BRDF's local "
                             f"slope: {BACKLASH_CORRECTION_FRACTION:.0%} of it, common to the "
                             "bins"}
NONLINEAR_FRACTION = 0.1
MC_DRAWS = 512
NEIGHBOURS = 8
"""Neighbours setting a local fit's bandwidth (the distance to the eighth)."""
GROWTH_STEPS = 5
SPREAD_FRACTION = 0.2
"""A neighbourhood must span this fraction of its bandwidth in every coordinate."""
STEP_DEG = 1e-3
FIT_BATCH = 256
"""Local fits solved together (memory: FIT_BATCH × neighbours × 10 floats)."""
RAD = np.pi / 180.0


@dataclass(frozen=True)
class AngularSources:
    """The rig's stated joint errors (deg, ``joint_names`` order) and the calibration."""

    joint_names: tuple[str, ...]
    backlash_deg: np.ndarray
    """The stated backlash the reduction corrects (0 where a calibration measured it)."""
    noise_deg: np.ndarray
    alignment: Alignment | None
    source_radius_deg: float = 0.0
    """Angular radius of the lamp's disc seen from the sample, deg."""
    pointing: bool = False
    """An image-based rig: the calibration's camera pointing (with its 1σ) is a parameter."""

    @classmethod
    def of(cls, rig: RigConfig, geo: SampleGeometry) -> AngularSources:
        """The rig file's stated errors and ``geo``'s calibration (a backlash the calibration
        measured is corrected with it, its 1σ in the calibration's covariance; a stated one
        is corrected by ``geo`` too, its uncertainty the ``backlash`` term)."""
        names = geo.kinematics.joint_names
        return cls(names, np.array([geo.stated_backlash_deg.get(n, 0.0) for n in names], float),
                   np.array([rig.axes[n].position_noise_deg for n in names], float),
                   geo.alignment,
                   float(np.degrees(rig.light_source_diameter_m / 2.0 / rig.light_distance_m)),
                   rig.sample.image_based)

    @property
    def independent(self) -> bool:
        return bool(np.any(self.noise_deg > 0))

    @property
    def stated_backlash(self) -> bool:
        """Whether a stated backlash is corrected (the ``backlash`` term)."""
        return bool(np.any(self.backlash_deg > 0))

    @property
    def joints_needed(self) -> bool:
        """Whether a term needs the Jacobians with respect to the joints."""
        return self.independent or self.stated_backlash

    @property
    def source(self) -> bool:
        return self.source_radius_deg > 0

    @property
    def correlated(self) -> bool:
        return bool(np.any(np.diag(self.calibration_covariance()) > 0))

    @property
    def calibration_names(self) -> tuple[str, ...]:
        """The calibration's parameters: the alignment's, then (image-based rigs) the camera
        pointing's :data:`POINTING_PARAMS` where the alignment's fit did not hold them."""
        if self.alignment is None:
            return ()
        names = self.alignment.param_names
        return names + tuple(n for n in POINTING_PARAMS if self.pointing and n not in names)

    def calibration_covariance(self) -> np.ndarray:
        """Covariance (P, P), deg², of :attr:`calibration_names` (an undetermined entry: 0;
        a pointing measured apart from the fit: uncorrelated with the rest)."""
        a = self.alignment
        if a is None:
            return np.zeros((0, 0))
        p = len(a.param_names)
        names = self.calibration_names
        cov = np.zeros((len(names),) * 2)
        if a.covariance_deg2 is not None and p:
            cov[:p, :p] = np.where(np.isfinite(a.covariance_deg2), a.covariance_deg2, 0.0)
        for k, name in enumerate(names[p:], start=p):
            cov[k, k] = a.camera_pointing_sigma_deg[POINTING_PARAMS.index(name)] ** 2
        return cov


def central_difference(pose_of: Callable[[float], np.ndarray]) -> np.ndarray:
    """d(θi, θr, Δφ)/d parameter (N, 3) from ``pose_of(step_deg)``: the poses (N, 3) with the
    parameter moved by ``step_deg`` (central differences of :data:`STEP_DEG`, Δφ wrapped)."""
    d = pose_of(STEP_DEG) - pose_of(-STEP_DEG)
    d[:, 2] = wrap_deg_array(d[:, 2])
    return d / (2 * STEP_DEG)


def pose_jacobians(kin: Kinematics, joints: np.ndarray) -> np.ndarray:
    """d(θi, θr, Δφ)/d joint (N, 3, J) at joints (N, J)."""

    def moved(j: int) -> Callable[[float], np.ndarray]:
        return lambda step: kin.poses_array(joints + step * np.eye(joints.shape[1])[j])

    return np.stack([central_difference(moved(j)) for j in range(joints.shape[1])], axis=2)


def calibration_jacobians(geo: SampleGeometry, names: tuple[str, ...], joints: np.ndarray
                          ) -> np.ndarray:
    """d(θi, θr, Δφ)/d calibration parameter ``names`` (N, 3, P) at joints (N, J): ``geo``'s
    corrections with one parameter moved."""
    corrections = geo.corrections
    assert corrections is not None

    def moved(name: str) -> Callable[[float], np.ndarray]:
        return lambda step: CalibratedKinematics(
            geo.base, corrections.shifted(name, step)).poses_array(joints)

    return np.stack([central_difference(moved(n)) for n in names], axis=2)


def folded_jacobians(jac: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Jacobians (N, 3, K) of (θi, θr, Δφ) as those of (θi, θr, |Δφ|), the local models'
    coordinates, at poses (N, 3); the azimuth of a direction at the normal does not matter
    (its row is 0 where θi or θr is below 1°)."""
    out = np.array(jac, float)
    out[:, 2, :] *= np.where(wrap_deg_array(poses[:, 2]) < 0, -1.0, 1.0)[:, None]
    out[np.minimum(poses[:, 0], poses[:, 1]) < 1.0, 2, :] = 0.0
    return out


def _augmented(poses: np.ndarray, log_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every sample with its reciprocal (θi ↔ θr) and its Δφ mirrored about 0° and 180°."""
    ti, tr, dp = poses[:, 0], poses[:, 1], np.abs(wrap_deg_array(poses[:, 2]))
    rows, values = [], []
    for a, b in ((ti, tr), (tr, ti)):
        for phi in (dp, -dp, 360.0 - dp):
            rows.append(np.column_stack([a, b, phi]))
            values.append(log_f)
    return np.vstack(rows), np.vstack(values)


def _pairs(dim: int) -> list[tuple[int, int]]:
    """The cross terms of a quadratic in ``dim`` coordinates: (0, 1), (0, 2), (1, 2), …"""
    return [(i, j) for i in range(dim) for j in range(i + 1, dim)]


def _quadratic_design(d: np.ndarray) -> np.ndarray:
    """Columns 1, each x, each x²/2, each cross product (:func:`_pairs`) of offsets (n, D)."""
    dim = d.shape[1]
    return np.column_stack([np.ones(len(d)), d, d * d / 2,
                            *(d[:, i] * d[:, j] for i, j in _pairs(dim))])


def _unpack(coef: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (N, C, D) and Hessians (N, C, D, D) of fitted quadratics (coef (N, Q, C) in
    :func:`_quadratic_design`'s order)."""
    g = coef[:, 1:1 + dim].transpose(0, 2, 1)
    h = np.empty((coef.shape[0], coef.shape[2], dim, dim))
    for i in range(dim):
        h[..., i, i] = coef[:, 1 + dim + i]
    for k, (i, j) in enumerate(_pairs(dim)):
        h[..., i, j] = h[..., j, i] = coef[:, 1 + 2 * dim + k]
    return g, h


def local_log_models(poses: np.ndarray, log_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (N, C, 3) and Hessian (N, C, 3, 3) of ln f in (θi, θr, |Δφ|), per degree, at
    every sample (:func:`local_models`, its samples with their reciprocals and Δφ mirrors,
    Δφ distances × √(sin θi sin θr) of the centre: a plan at one θi gets θi from the
    reciprocal samples)."""
    aug, values = _augmented(poses, log_f)
    centres = np.column_stack([poses[:, 0], poses[:, 1], np.abs(wrap_deg_array(poses[:, 2]))])
    w_phi = np.sqrt(np.maximum(np.sin(centres[:, 0] * RAD) * np.sin(centres[:, 1] * RAD), 1e-6))
    return local_models(centres, w_phi, aug, values)


def local_models(centres: np.ndarray, w_last: np.ndarray, points: np.ndarray,
                 values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (N, C, D) and Hessian (N, C, D, D), per degree, of the values (M, C) known at
    ``points`` (M, D, deg) at each of N ``centres``: a weighted quadratic over the centre's
    neighbours (:func:`_fits`). The neighbourhood (Gaussian weights, out to 2.5 bandwidths,
    the first bandwidth the distance to the :data:`NEIGHBOURS`-th) grows until its points vary
    in every coordinate; the last coordinate's offsets count × ``w_last`` (N,) ≤ 1 of the
    centre. A k-d tree offers each centre only the points that can lie in its neighbourhood
    (:class:`_Candidates`; the result is that of comparing every pair)."""
    cand = _Candidates.of(points, centres, w_last)
    first = cand.first_neighbourhoods(SPREAD_FRACTION)
    grown = []
    for k in np.flatnonzero(~first.spanned):  # grow the bandwidth
        h = first.bandwidth[k] * 1.5
        for _ in range(GROWTH_STEPS - 1):
            idx, d, dist = cand.within(k, 2.5 * h)
            near = dist <= 2.5 * h
            if np.all(np.ptp(d[near], axis=0) > SPREAD_FRACTION * h):
                break
            h *= 1.5
        grown.append((d[near], idx[near], np.exp(-0.5 * (dist[near] / h) ** 2)))
    keep = first.near & np.repeat(first.spanned, np.diff(first.start))
    owner = np.repeat(np.arange(len(centres)), np.diff(first.start))[keep]
    weight = np.exp(-0.5 * (first.dist[keep] / first.bandwidth[owner]) ** 2)
    index = np.concatenate([first.index[keep], *(g[1] for g in grown)])
    order = np.concatenate([np.flatnonzero(first.spanned), np.flatnonzero(~first.spanned)])
    g_, h_ = _fits(np.concatenate([first.offset[keep], *(g[0] for g in grown)]),
                   values[index], np.concatenate([weight, *(g[2] for g in grown)]),
                   np.concatenate([np.bincount(owner, minlength=len(centres))[first.spanned],
                                   [len(g[1]) for g in grown]]).astype(np.intp))
    grads, hessians = np.empty_like(g_), np.empty_like(h_)
    grads[order], hessians[order] = g_, h_
    w = np.asarray(w_last, float)[:, None]
    grads[:, :, -1] *= w
    hessians[:, :, -1, :] *= w[:, :, None]
    hessians[:, :, :, -1] *= w[:, :, None]
    return grads, hessians


@dataclass(frozen=True)
class _FirstNeighbourhoods:
    """Every centre's candidates at once (grouped by centre, nearest first), its first
    bandwidth, and whether the points within 2.5 of it vary in every coordinate."""

    start: np.ndarray
    index: np.ndarray
    offset: np.ndarray
    dist: np.ndarray
    bandwidth: np.ndarray
    near: np.ndarray
    spanned: np.ndarray


@dataclass(frozen=True)
class _Candidates:
    """The points that may lie within a scaled distance of each centre (last offsets count
    × the centre's ``w_phi`` ≤ 1). Centres are banded by ``w_phi`` (w ∈ (2⁻ᵇ⁻¹, 2⁻ᵇ]); each
    band's k-d tree holds the points with the last coordinate × the band's least w, so its
    distances are at most the scaled ones and a ball of the scaled radius holds every point
    within it.
    :meth:`first` covers the first bandwidth (the distance to the ``k_nb``-th neighbour, at
    least 1e-3°) out to 2.5 bandwidths."""

    trees: dict[int, Any]
    scales: dict[int, np.ndarray]
    aug: np.ndarray
    centres: np.ndarray
    w_phi: np.ndarray
    band: np.ndarray
    k_nb: int
    radius: np.ndarray
    """Scaled radius (deg) each centre's first candidates cover."""
    found: list[Any]

    @classmethod
    def of(cls, aug: np.ndarray, centres: np.ndarray, w_phi: np.ndarray) -> _Candidates:
        from scipy.spatial import cKDTree  # loaded by the reductions that need it

        w_phi = np.asarray(w_phi, float)
        band = np.clip(np.floor(-np.log2(w_phi)), 0, 30).astype(int)
        k_nb = min(NEIGHBOURS, len(aug) - 1)
        trees, scales, radius, found = {}, {}, np.zeros(len(centres)), [None] * len(centres)
        for b in np.unique(band):
            members = np.flatnonzero(band == b)
            scale = np.ones(centres.shape[1])
            scale[-1] = w_phi[members].min()
            trees[int(b)] = tree = cKDTree(aug * scale)
            scales[int(b)] = scale
            at = centres[members] * scale
            kth = np.asarray(tree.query(at, k=k_nb + 1)[0]).reshape(len(members), -1)[:, -1]
            ratio = w_phi[members] / scale[-1]  # the k-th scaled distance: ≤ ratio × kth
            radius[members] = 2.5 * np.maximum(ratio * kth, 1e-3)
            for m, f in zip(members, tree.query_ball_point(at, cls._margin(radius[members]),
                                                           return_sorted=True), strict=True):
                found[m] = f
        return cls(trees, scales, aug, centres, w_phi, band, k_nb, radius, found)

    @staticmethod
    def _margin(radius: Any) -> Any:
        return radius * (1.0 + 1e-9) + 1e-9

    def first_neighbourhoods(self, spread: float) -> _FirstNeighbourhoods:
        """Every centre's first candidates, bandwidth (the ``k_nb``-th distance, at least
        1e-3°) and whether the points within 2.5 bandwidths span every coordinate by more
        than ``spread`` × the bandwidth."""
        n = len(self.centres)
        counts = np.array([len(f) for f in self.found], dtype=np.intp)
        owner = np.repeat(np.arange(n), counts)
        index = np.concatenate([np.asarray(f, dtype=np.intp) for f in self.found])
        offset = self.aug[index] - self.centres[owner]
        offset[:, -1] *= self.w_phi[owner]
        dist = np.sqrt(np.sum(offset * offset, axis=1))
        order = np.lexsort((dist, owner))
        index, offset, dist = index[order], offset[order], dist[order]
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        bandwidth = np.maximum(dist[start[:-1] + self.k_nb], 1e-3)
        near = dist <= 2.5 * np.repeat(bandwidth, counts)
        high = np.maximum.reduceat(np.where(near[:, None], offset, -np.inf), start[:-1])
        low = np.minimum.reduceat(np.where(near[:, None], offset, np.inf), start[:-1])
        spanned = np.all(high - low > spread * bandwidth[:, None], axis=1)
        return _FirstNeighbourhoods(start, index, offset, dist, bandwidth, near, spanned)

    def within(self, k: int, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The same for the candidates within scaled ``radius`` (deg) of centre k."""
        b = int(self.band[k])
        at = self.centres[k] * self.scales[b]
        found = self.trees[b].query_ball_point(at, self._margin(radius), return_sorted=True)
        return self._offsets(k, np.asarray(found, dtype=np.intp))

    def _offsets(self, k: int, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = self.aug[idx] - self.centres[k]
        d[:, -1] *= self.w_phi[k]
        return idx, d, np.sqrt(np.sum(d * d, axis=1))


def _fits(d: np.ndarray, y: np.ndarray, weight: np.ndarray, sizes: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (N, C, D) and Hessians (N, C, D, D) at the origin of weighted quadratic fits
    to N neighbourhoods, given one after the other (``sizes`` (N,) rows each: offsets (n, D),
    values (n, C), weights (n,)): the least-norm solution, so a term the neighbours cannot
    fix (a cross term when they lie on lines through the centre) stays 0; linear where not
    even that; zero with fewer still. Solved in batches (:func:`_lstsq`), each coordinate
    scaled by its largest offset."""
    dim, channels = d.shape[1], y.shape[1]
    quadratic, linear = 1 + 2 * dim + len(_pairs(dim)), 1 + dim
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.intp)
    coef = np.zeros((len(sizes), quadratic, channels))
    if not len(sizes):
        return _unpack(coef, dim)
    scale = np.maximum(np.maximum.reduceat(np.abs(d), start, axis=0), 1e-6)
    sw = np.sqrt(weight)[:, None]
    design = _quadratic_design(d / np.repeat(scale, sizes, axis=0)) * sw
    y = y * sw
    done = np.zeros(len(sizes), bool)
    for cols, need in ((quadratic, quadratic - len(_pairs(dim))), (linear, dim)):
        todo = np.flatnonzero(~done & (sizes >= need))
        todo = todo[np.argsort(sizes[todo], kind="stable")]
        for chunk in np.array_split(todo, max(1, -(-len(todo) // FIT_BATCH))):
            if not len(chunk):
                continue
            n = sizes[chunk]
            local = np.repeat(np.arange(len(chunk)), n)
            rows = np.repeat(start[chunk] - np.cumsum(n) + n, n) + np.arange(n.sum())
            pos = rows - np.repeat(start[chunk], n)
            a = np.zeros((len(chunk), n.max(), cols))
            b = np.zeros((len(chunk), n.max(), channels))
            a[local, pos], b[local, pos] = design[rows, :cols], y[rows]
            x, rank = _lstsq(a, b)
            ok = rank >= need
            coef[chunk[ok], :cols] = x[ok]
            done[chunk[ok]] = True
    g, h = _unpack(coef, dim)
    return g / scale[:, None, :], h / (scale[:, None, :, None] * scale[:, None, None, :])


def _lstsq(a: np.ndarray, b: np.ndarray, rcond: float = 1e-8) -> tuple[np.ndarray, np.ndarray]:
    """Least-norm least-squares solutions (B, K, C) of a batch a (B, M, K) x = b (B, M, C), and
    their ranks (B,): numpy's ``lstsq`` rule (singular values ≤ rcond × the largest count as
    0); zero rows (padding) change nothing."""
    u, s, vh = np.linalg.svd(a, full_matrices=False)
    keep = s > rcond * s[:, :1]
    inv = np.where(keep, 1.0 / np.where(keep, s, 1.0), 0.0)
    x = np.swapaxes(vh, 1, 2) @ (inv[..., None] * (np.swapaxes(u, 1, 2) @ b))
    return x, keep.sum(axis=1)


def with_irradiance(grad: np.ndarray, hess: np.ndarray, theta_i: np.ndarray, axis: int = 0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The local model of ln f (gradient (N, C, D), Hessian (N, C, D, D), per degree) as that
    of the measured value: plus ln cos θi_true − ln cos θi (what dividing by the assumed
    irradiance leaves), θi (deg) being coordinate ``axis`` (0 in (θi, θr, |Δφ|))."""
    t = np.tan(theta_i * RAD)
    g, h = grad.copy(), hess.copy()
    g[:, :, axis] -= t[:, None] * RAD
    h[:, :, axis, axis] -= ((1.0 + t * t) * RAD**2)[:, None]
    return g, h


def relative_variances(grad: np.ndarray, hess: np.ndarray, pose_cov: np.ndarray,
                       draws: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Relative variance (N, C) of values whose logarithm has the local model ``grad``
    (N, C, D), ``hess`` (N, C, D, D) for coordinate errors of covariance (N, D, D): first
    order where adequate, else the Monte Carlo over ``draws(k)`` (the coordinate errors
    (len(k), M, D) of samples k) when given, else the second-order form for Gaussian errors
    (the mean shift included)."""
    g, h = grad, hess
    first = np.einsum("nci,nij,ncj->nc", g, pose_cov, g)
    hs = np.einsum("ncij,njk->ncik", h, pose_cov)
    bias = 0.5 * np.einsum("ncii->nc", hs)
    second = 0.5 * np.einsum("ncij,ncji->nc", hs, hs)
    out = first + second + bias**2
    near = (second + bias**2) > NONLINEAR_FRACTION * first
    if draws is not None and near.any():
        k = np.flatnonzero(np.any(near, axis=1))
        d = draws(k)[:, None]  # (n, 1, M, D)
        lin = np.matmul(d, g[k][..., None])[..., 0]
        quad = 0.5 * np.sum(np.matmul(d, h[k]) * d, axis=-1)
        mc = np.mean(np.expm1(np.clip(lin + quad, -50.0, 50.0)) ** 2, axis=2)
        out[k] = np.where(near[k], mc, out[k])
    return out


def joint_draws(sources: AngularSources, jac: np.ndarray, seed: int = 0) -> np.ndarray:
    """Coordinate errors (N, M, D) of :data:`MC_DRAWS` fixed draws of the joints' position
    noise (Gaussian) through the Jacobians (N, D, J)."""
    rng = np.random.default_rng(seed)
    dj = rng.standard_normal((MC_DRAWS, len(sources.joint_names))) * sources.noise_deg
    return np.swapaxes(np.matmul(jac, dj.T), 1, 2)


def disc_covariance(poses: np.ndarray, radius_deg: float) -> np.ndarray:
    """Covariance (N, 3, 3), deg², of the light's direction over the lamp's disc in
    (θi, θr, |Δφ|): ρ²/4 in θi and ρ²/(4 sin² θi) in Δφ."""
    var = radius_deg**2 / 4.0
    sin2 = np.maximum(np.sin(poses[:, 0] * RAD) ** 2, 1e-6)
    out = np.zeros((len(poses), 3, 3))
    out[:, 0, 0], out[:, 2, 2] = var, var / sin2
    return out


def source_bias(grad: np.ndarray, hess: np.ndarray, disc_cov: np.ndarray) -> np.ndarray:
    """Relative bias (N, C) of averaging over the lamp's disc: ½ tr(H Σ) + ½ Gᵀ Σ G with Σ
    (N, D, D) the disc's covariance in the local model's coordinates."""
    return 0.5 * np.einsum("ncij,nji->nc", hess, disc_cov) \
        + 0.5 * np.einsum("nci,nij,ncj->nc", grad, disc_cov, grad)


@dataclass(frozen=True)
class AngularTerms:
    """Per sample: the angular variance (N, 3), sr⁻²; the calibration's and the stated
    backlash's standard uncertainties (N, 3), sr⁻¹; the source-size bias (N, 3), relative (the
    value is f·(1 + bias))."""

    variance: np.ndarray
    calibration: np.ndarray
    source_bias: np.ndarray
    backlash: np.ndarray

    @classmethod
    def zeros(cls, n: int) -> AngularTerms:
        return cls(*(np.zeros((n, 3)) for _ in range(4)))


def angular_terms(sources: AngularSources, geo: SampleGeometry, joints: np.ndarray,
                  poses: np.ndarray, values: np.ndarray) -> AngularTerms:
    """Each sample's angular terms (:class:`AngularTerms`; zeros where the rig states no such
    error) at read-back joints (N, J), claimed poses (N, 3) and values (N, 3): the local
    models from the samples themselves, the Jacobians from ``geo``'s kinematics."""
    poses = np.asarray(poses, float)
    n = len(poses)
    if n == 0 or not (sources.joints_needed or sources.correlated or sources.source):
        return AngularTerms.zeros(n)
    grad, hess = with_irradiance(
        *local_log_models(poses, np.log(np.maximum(np.abs(values), 1e-300))), poses[:, 0])
    jac = (folded_jacobians(pose_jacobians(geo.kinematics, joints), poses)
           if sources.joints_needed else None)
    kcal = (folded_jacobians(calibration_jacobians(geo, sources.calibration_names, joints), poses)
            if sources.correlated else None)
    disc = disc_covariance(poses, sources.source_radius_deg) if sources.source else None
    return terms_at(sources, grad, hess, values, jac, kcal, disc)


def terms_at(sources: AngularSources, grad: np.ndarray, hess: np.ndarray, values: np.ndarray,
             joint_jac: np.ndarray | None, calibration_jac: np.ndarray | None,
             disc_cov: np.ndarray | None) -> AngularTerms:
    """The angular terms of N samples (or groups of samples that share their errors) with
    values (N, 3), given the local model of the logarithm of the measured value there
    (gradient (N, C, D), Hessian (N, C, D, D) in D coordinates, the assumed irradiance
    included: :func:`with_irradiance`), the Jacobians of those coordinates with respect to the
    joints (N, D, J) and to :attr:`AngularSources.calibration_names` (N, D, P), and the lamp
    disc's covariance in them (N, D, D); a term whose Jacobian or covariance is None is 0."""
    out = AngularTerms.zeros(len(values))
    if disc_cov is not None:
        out.source_bias[:] = source_bias(grad, hess, disc_cov)
    if joint_jac is not None and sources.independent:
        cov = np.einsum("nij,j,nkj->nik", joint_jac, sources.noise_deg**2, joint_jac)
        out.variance[:] = relative_variances(
            grad, hess, cov, lambda k: joint_draws(sources, joint_jac[k])) * values**2
    if joint_jac is not None and sources.stated_backlash:
        half = BACKLASH_CORRECTION_FRACTION * sources.backlash_deg / 2.0
        cov = np.einsum("nij,j,nkj->nik", joint_jac, half**2, joint_jac)
        out.backlash[:] = np.sqrt(relative_variances(grad, hess, cov)) * np.abs(values)
    if calibration_jac is not None:
        cov = np.einsum("nip,pq,njq->nij", calibration_jac, sources.calibration_covariance(),
                        calibration_jac)
        out.calibration[:] = np.sqrt(relative_variances(grad, hess, cov)) * np.abs(values)
    return out
