"""Closest approach of two line segments (the axes of the arms' capsules), vectorised."""

from __future__ import annotations

import numpy as np


def segment_params(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where segments p1–q1 and p2–q2 (…, 3) come closest: the fractions (s, t) ∈ [0, 1] along
    each, vectorised."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    denom = a * e - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > 1e-15, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = np.where(e > 1e-15, (b * s + f) / e, 0.0)
        s = np.where(t < 0, np.where(a > 1e-15, np.clip(-c / a, 0, 1), 0.0), s)
        s = np.where(t > 1, np.where(a > 1e-15, np.clip((b - c) / a, 0, 1), 0.0), s)
        t = np.clip(t, 0.0, 1.0)
    return s, t


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Shortest distance between segments p1–q1 and p2–q2 (…, 3), vectorised."""
    s, t = segment_params(p1, q1, p2, q2)
    gap = (p1 + (q1 - p1) * s[..., None]) - (p2 + (q2 - p2) * t[..., None])
    return np.linalg.norm(gap, axis=-1)
