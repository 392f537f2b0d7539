"""Angular uncertainty of every sample: where the arms really were, through the BRDF's slope.

A sample's value belongs to the pose the reduction's geometry model gives its read-back joints
(the geometric calibration's, when one is applied). The arms stood a little elsewhere:

* independent per sample — each axis' position noise (σ) as the rig file states it
  (``[axes.NAME] position_noise_deg``; a rig with backlash approaches every target afresh, so
  each step draws it anew), and its backlash (``backlash_deg``: the arm stops ``b/2`` behind
  the centre of its play) where no calibration corrects it (±b/2, equally likely);
* common to every sample — the geometric calibration's own error (its covariance of zero
  offsets, tilt and backlash);
* the lamp's size (``[light] source_diameter_m``): a value is the BRDF averaged over the
  directions of a disc, not its value at the disc's centre — a bias of
  ½ tr(H Σ) + ½ Gᵀ Σ G (Σ: the disc's direction covariance, ρ²/4 in each of its two
  directions; negative at a peak, where the curvature is). The reduction corrects it and
  budgets :data:`SOURCE_CORRECTION_FRACTION` of the correction as its uncertainty (the
  curvature is the measurement's own, itself blurred and sampled).

Each joint error moves the pose by the kinematics' Jacobian (:func:`pose_jacobians`), and the
measured value by the BRDF's relative change there, times cos θi_true / cos θi (the
irradiance the reduction divides by). The BRDF's local variation comes from the measurement
itself: a weighted quadratic fit of ln f over each sample's neighbours
(:func:`local_log_models`; reciprocity and Δφ ↔ −Δφ supply neighbours on every side). Where the
first-order term Gᵀ Σ G is adequate it is used; near an extremum (a peak, where the gradient
vanishes and the curvature rules: second-order terms above :data:`NONLINEAR_FRACTION` of it)
the independent term is a Monte Carlo over :data:`MC_DRAWS` fixed draws of the joint errors
(GUM Supplement 1), the correlated one the second-order closed form for Gaussian errors. Both
are returned as relative variances of the sample's value.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.kinematics import Kinematics
from acquisition.geometry.kinematics.base import wrap_deg_array
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics

ANGULAR_TERM = {"angular": "the arms' position noise and any backlash no calibration "
                           "corrects (rig file) through the BRDF's local slope and "
                           "curvature, independent"}
CALIBRATION_TERM = {"geometry_calibration": "the geometric calibration's 1σ (zero offsets, "
                                            "sample tilt, backlash) through the BRDF's local "
                                            "slope, common to the bins"}
SOURCE_TERM = {"source_size": "the correction for the lamp's disc (rig file's [light] "
                              "source_diameter_m) blurring the BRDF by its local curvature, "
                              "independent"}
SOURCE_CORRECTION_FRACTION = 0.3
"""Standard uncertainty of the source-size correction, as a fraction of it."""
NONLINEAR_FRACTION = 0.1
MC_DRAWS = 512
NEIGHBOURS = 8
"""Neighbours setting a local fit's bandwidth (the distance to the eighth)."""
GROWTH_STEPS = 5
SPREAD_FRACTION = 0.2
"""A neighbourhood must span this fraction of its bandwidth in every coordinate."""
STEP_DEG = 1e-3
RAD = np.pi / 180.0


@dataclass(frozen=True)
class AngularSources:
    """The rig's stated joint errors (deg, ``joint_names`` order) and the calibration."""

    joint_names: tuple[str, ...]
    backlash_deg: np.ndarray
    noise_deg: np.ndarray
    alignment: Alignment | None
    source_radius_deg: float = 0.0
    """Angular radius of the lamp's disc seen from the sample, deg."""

    @classmethod
    def of(cls, rig: RigConfig, kinematics: Kinematics,
           alignment: Alignment | None) -> AngularSources:
        """The rig file's stated errors (a backlash the calibration measured is corrected, not
        an uncertainty of its own: its 1σ is in the calibration's covariance)."""
        names = kinematics.joint_names
        measured = {} if alignment is None else alignment.backlash_deg
        axes = rig.axes
        return cls(names,
                   np.array([0.0 if n in measured else axes[n].backlash_deg for n in names],
                            float),
                   np.array([axes[n].position_noise_deg for n in names], float),
                   alignment,
                   float(np.degrees(rig.light_source_diameter_m / 2.0 / rig.light_distance_m)))

    @property
    def independent(self) -> bool:
        return bool(np.any(self.backlash_deg > 0) or np.any(self.noise_deg > 0))

    @property
    def source(self) -> bool:
        return self.source_radius_deg > 0

    @property
    def correlated(self) -> bool:
        a = self.alignment
        return a is not None and a.covariance_deg2 is not None and bool(a.param_names)


def pose_jacobians(kin: Kinematics, joints: np.ndarray) -> np.ndarray:
    """d(θi, θr, Δφ)/d joint (N, 3, J) at joints (N, J), central differences."""
    out = np.empty((len(joints), 3, joints.shape[1]))
    for j in range(joints.shape[1]):
        up, down = joints.copy(), joints.copy()
        up[:, j] += STEP_DEG
        down[:, j] -= STEP_DEG
        d = kin.poses_array(up) - kin.poses_array(down)
        d[:, 2] = wrap_deg_array(d[:, 2])
        out[:, :, j] = d / (2 * STEP_DEG)
    return out


def calibration_jacobians(base: Kinematics, alignment: Alignment, joints: np.ndarray
                          ) -> np.ndarray:
    """d(θi, θr, Δφ)/d calibration parameter (N, 3, P) at joints (N, J)."""
    out = np.empty((len(joints), 3, len(alignment.param_names)))
    for k, name in enumerate(alignment.param_names):
        up = CalibratedKinematics(base, alignment.shifted(name, STEP_DEG)).poses_array(joints)
        down = CalibratedKinematics(base, alignment.shifted(name, -STEP_DEG)).poses_array(joints)
        d = up - down
        d[:, 2] = wrap_deg_array(d[:, 2])
        out[:, :, k] = d / (2 * STEP_DEG)
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


def _quadratic_design(d: np.ndarray) -> np.ndarray:
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return np.column_stack([np.ones_like(x), x, y, z, x * x / 2, y * y / 2, z * z / 2,
                            x * y, x * z, y * z])


def _unpack(coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (C, 3) and Hessian (C, 3, 3) of a fitted quadratic (coef (10, C))."""
    g = coef[1:4].T
    h = np.empty((coef.shape[1], 3, 3))
    h[:, 0, 0], h[:, 1, 1], h[:, 2, 2] = coef[4], coef[5], coef[6]
    h[:, 0, 1] = h[:, 1, 0] = coef[7]
    h[:, 0, 2] = h[:, 2, 0] = coef[8]
    h[:, 1, 2] = h[:, 2, 1] = coef[9]
    return g, h


def local_log_models(poses: np.ndarray, log_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (N, C, 3) and Hessian (N, C, 3, 3) of ln f in (θi, θr, |Δφ|), per degree, at
    every sample: a weighted quadratic over its neighbours (:func:`_fit`). The neighbourhood
    (Gaussian weights, out to 2.5 bandwidths) grows until its samples vary in every
    coordinate (a plan at one θi gets θi from the reciprocal samples); Δφ distances count
    × √(sin θi sin θr) of the centre."""
    aug, values = _augmented(poses, log_f)
    n, c = log_f.shape
    grads, hessians = np.zeros((n, c, 3)), np.zeros((n, c, 3, 3))
    for k in range(n):
        centre = np.array([poses[k, 0], poses[k, 1], abs(wrap_deg_array(poses[k, 2]))])
        w_phi = float(np.sqrt(max(np.sin(centre[0] * RAD) * np.sin(centre[1] * RAD), 1e-6)))
        d = (aug - centre) * [1.0, 1.0, w_phi]
        dist = np.sqrt(np.sum(d * d, axis=1))
        h = max(float(np.sort(dist)[min(NEIGHBOURS, len(dist) - 1)]), 1e-3)
        for _ in range(GROWTH_STEPS):
            near = dist <= 2.5 * h
            if np.all(np.ptp(d[near], axis=0) > SPREAD_FRACTION * h):
                break
            h *= 1.5
        weight = np.exp(-0.5 * (dist[near] / h) ** 2)
        g, hess = _fit(d[near], values[near], weight)
        g[:, 2] *= w_phi
        hess[:, 2, :] *= w_phi
        hess[:, :, 2] *= w_phi
        grads[k], hessians[k] = g, hess
    return grads, hessians


def _fit(d: np.ndarray, y: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient and Hessian of the weighted quadratic fit at the origin: the least-norm
    solution, so a term the neighbours cannot fix (a cross term when they lie on lines
    through the centre) stays 0; linear where not even that; zero with fewer still."""
    sw = np.sqrt(weight)[:, None]
    scale = np.maximum(np.max(np.abs(d), axis=0), 1e-6)
    for cols, need in ((10, 7), (4, 3)):
        if len(d) < need:
            continue
        design = _quadratic_design(d / scale)[:, :cols]
        coef, _, rank, _ = np.linalg.lstsq(design * sw, y * sw, rcond=1e-8)
        if rank >= need:
            full = np.zeros((10, y.shape[1]))
            full[:cols] = coef
            g, h = _unpack(full)
            return g / scale, h / np.outer(scale, scale)
    return np.zeros((y.shape[1], 3)), np.zeros((y.shape[1], 3, 3))


def _with_irradiance(grad: np.ndarray, hess: np.ndarray, theta_i: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Add ln cos θi_true − ln cos θi (what dividing by the assumed irradiance leaves)."""
    t = np.tan(theta_i * RAD)
    g, h = grad.copy(), hess.copy()
    g[:, :, 0] -= t[:, None] * RAD
    h[:, :, 0, 0] -= ((1.0 + t * t) * RAD**2)[:, None]
    return g, h


def relative_variances(grad: np.ndarray, hess: np.ndarray, theta_i: np.ndarray,
                       pose_cov: np.ndarray, draws: np.ndarray | None = None) -> np.ndarray:
    """Relative variance (N, C) of the values for pose errors of covariance (N, 3, 3): first
    order where adequate, else the Monte Carlo over ``draws`` (N, M, 3) pose errors when
    given, else the second-order form for Gaussian errors (the mean shift included)."""
    g, h = _with_irradiance(grad, hess, theta_i)
    first = np.einsum("nci,nij,ncj->nc", g, pose_cov, g)
    hs = np.einsum("ncij,njk->ncik", h, pose_cov)
    bias = 0.5 * np.einsum("ncii->nc", hs)
    second = 0.5 * np.einsum("ncij,ncji->nc", hs, hs)
    out = first + second + bias**2
    near = (second + bias**2) > NONLINEAR_FRACTION * first
    if draws is not None and near.any():
        k = np.flatnonzero(np.any(near, axis=1))
        lin = np.einsum("nci,nmi->ncm", g[k], draws[k])
        quad = 0.5 * np.einsum("nmi,ncij,nmj->ncm", draws[k], h[k], draws[k])
        mc = np.mean(np.expm1(np.clip(lin + quad, -50.0, 50.0)) ** 2, axis=2)
        out[k] = np.where(near[k], mc, out[k])
    return out


def joint_draws(sources: AngularSources, jac: np.ndarray, seed: int = 0) -> np.ndarray:
    """Pose errors (N, M, 3) of :data:`MC_DRAWS` fixed draws of the joint errors: backlash ±b/2
    with equal odds, position noise Gaussian."""
    rng = np.random.default_rng(seed)
    m, j = MC_DRAWS, len(sources.joint_names)
    signs = rng.choice((-1.0, 1.0), size=(m, j))
    dj = signs * sources.backlash_deg / 2.0 + rng.standard_normal((m, j)) * sources.noise_deg
    return np.einsum("nij,mj->nmi", jac, dj)


def source_bias(grad: np.ndarray, hess: np.ndarray, poses: np.ndarray, radius_deg: float
                ) -> np.ndarray:
    """Relative bias (N, C) of averaging over the lamp's disc: ½ tr(H Σ) + ½ Gᵀ Σ G with Σ
    the disc's spread in (θi, |Δφ|): ρ²/4 and ρ²/(4 sin² θi) (deg²)."""
    g, h = _with_irradiance(grad, hess, poses[:, 0])
    var = radius_deg**2 / 4.0
    sin2 = np.maximum(np.sin(poses[:, 0] * RAD) ** 2, 1e-6)
    d = np.stack([np.full(len(poses), var), np.zeros(len(poses)), var / sin2], axis=1)
    return 0.5 * np.einsum("ncii,ni->nc", h, d) + 0.5 * np.einsum("nci,ni,nci->nc", g, d, g)


@dataclass(frozen=True)
class AngularTerms:
    """Per sample: the angular variance (N, 3), sr⁻²; the calibration's standard uncertainty
    (N, 3), sr⁻¹; the source-size bias (N, 3), relative (the value is f·(1 + bias))."""

    variance: np.ndarray
    calibration: np.ndarray
    source_bias: np.ndarray


def angular_terms(sources: AngularSources, kin: Kinematics, base: Kinematics,
                  joints: np.ndarray, poses: np.ndarray, values: np.ndarray) -> AngularTerms:
    """Each sample's angular terms (:class:`AngularTerms`; zeros where the rig states no such
    error) at read-back joints (N, J), claimed poses (N, 3) and values (N, 3)."""
    poses = np.asarray(poses, float)
    n = len(poses)
    out = AngularTerms(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)))
    if n == 0 or not (sources.independent or sources.correlated or sources.source):
        return out
    log_f = np.log(np.maximum(np.abs(values), 1e-300))
    grad, hess = local_log_models(poses, log_f)
    sign = np.where(wrap_deg_array(poses[:, 2]) < 0, -1.0, 1.0)
    degenerate = np.minimum(poses[:, 0], poses[:, 1]) < 1.0
    if sources.source:
        out.source_bias[:] = source_bias(grad, hess, poses, sources.source_radius_deg)
    if sources.independent:
        jac = pose_jacobians(kin, joints)
        jac[:, 2, :] *= sign[:, None]
        jac[degenerate, 2, :] = 0.0  # the azimuth of a direction at the normal does not matter
        sigma2 = (sources.backlash_deg / 2.0) ** 2 + sources.noise_deg**2
        cov = np.einsum("nij,j,nkj->nik", jac, sigma2, jac)
        out.variance[:] = relative_variances(grad, hess, poses[:, 0], cov,
                                             joint_draws(sources, jac)) * values**2
    if sources.correlated:
        a = sources.alignment
        assert a is not None and a.covariance_deg2 is not None
        c = np.where(np.isfinite(a.covariance_deg2), a.covariance_deg2, 0.0)
        kcal = calibration_jacobians(base, a, joints)
        kcal[:, 2, :] *= sign[:, None]
        kcal[degenerate, 2, :] = 0.0
        cov = np.einsum("nip,pq,njq->nij", kcal, c, kcal)
        out.calibration[:] = np.sqrt(relative_variances(grad, hess, poses[:, 0], cov)) \
            * np.abs(values)
    return out
