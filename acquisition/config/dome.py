"""Light-stage dome geometry: light directions in the sample frame and their solid angles.

Directions are unit vectors from the sample towards each light, in the sample frame
(normal +z, so the dome is the upper hemisphere z > 0). A dome comes from the rig file
(:func:`load_dome`): an explicit list of directions or angles, or a geodesic generator.

The classic 156-light layout: a class-I geodesic sphere of frequency 6 (every icosahedron
face split into 6 × 6 triangles, 10·6² + 2 = 362 vertices), oriented with an icosahedron
vertex at the zenith. 166 vertices lie above the horizon; the lowest ring of 10, at 9.9°
elevation, is dropped by a 10° minimum elevation (it would light the sample at grazing
incidence and sit in the camera's way), leaving 156 lights from the zenith down to 10.1°.
:func:`geodesic_directions` finds this cut for any requested count that a frequency allows.

Each light's solid angle is the part of the upper hemisphere closer to it than to any other
light: spherical Voronoi cells (:class:`scipy.spatial.SphericalVoronoi`) of the lights plus
their mirror images below the horizon, so cell boundaries at the bottom follow the horizon
and the cells tile the hemisphere exactly (sum 2π sr). These are the quadrature weights for
image-based relighting; light arriving from below the horizon is outside the dome's reach.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivers.errors import ConfigError

_ELEVATION_TOL_DEG = 1e-6


def geodesic_sphere(frequency: int) -> np.ndarray:
    """Vertices (10·f² + 2, 3) of a class-I geodesic sphere with a vertex at +z.

    Every icosahedron face is split into ``frequency²`` triangles on a barycentric grid and
    the grid points are projected onto the unit sphere.
    """
    from scipy.spatial import ConvexHull

    if not 1 <= frequency <= 64:
        raise ValueError(f"geodesic frequency must be 1–64, got {frequency}")
    # icosahedron: poles on ±z, two rings of five at elevation ±atan(1/2)
    z = 1 / np.sqrt(5)
    r = 2 / np.sqrt(5)
    az = np.radians(np.arange(5) * 72.0)
    ico = np.vstack(
        [
            [0.0, 0.0, 1.0],
            np.column_stack([r * np.cos(az), r * np.sin(az), np.full(5, z)]),
            np.column_stack([r * np.cos(az + np.pi / 5), r * np.sin(az + np.pi / 5), np.full(5, -z)]),
            [0.0, 0.0, -1.0],
        ]
    )
    faces = ConvexHull(ico).simplices
    f = frequency
    ij = np.array([(i, j) for i in range(f + 1) for j in range(f + 1 - i)], dtype=float)
    bary = np.column_stack([ij, f - ij.sum(axis=1)]) / f  # (P, 3)
    points = np.einsum("pk,fkd->fpd", bary, ico[faces]).reshape(-1, 3)
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    # grid points on shared edges appear once per face: merge them
    _, first = np.unique(np.round(points, 9), axis=0, return_index=True)
    return points[np.sort(first)]


def _elevation_deg(directions: np.ndarray) -> np.ndarray:
    return np.degrees(np.arcsin(np.clip(directions[:, 2], -1.0, 1.0)))


def _azimuth_deg(directions: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(directions[:, 1], directions[:, 0])) % 360.0


def _sorted(directions: np.ndarray) -> np.ndarray:
    """Zenith first, then ring by ring downwards, each ring by azimuth."""
    el = np.round(_elevation_deg(directions), 6)
    az = np.round(_azimuth_deg(directions), 6) % 360.0
    return directions[np.lexsort((az, -el))]


def geodesic_directions(
    n_lights: int | None = None,
    *,
    frequency: int | None = None,
    min_elevation_deg: float = 0.0,
    azimuth_offset_deg: float = 0.0,
) -> np.ndarray:
    """Light directions (N, 3) of a geodesic dome, zenith first.

    Parameters
    ----------
    n_lights:
        Wanted number of lights; the lowest frequency (≤ 16) whose upper-hemisphere vertices,
        cut below some ring at or above ``min_elevation_deg``, number exactly this many. 156
        gives the classic layout (frequency 6, lights at ≥ 10.1° elevation). Default 156 when
        ``frequency`` is not given either.
    frequency:
        Use this frequency and keep every vertex above ``min_elevation_deg``.
    min_elevation_deg:
        Lowest elevation allowed (deg); vertices on the horizon are never kept.
    azimuth_offset_deg:
        Rotate the dome about the normal (deg).

    Raises
    ------
    ConfigError
        If both or no achievable count is asked for.
    """
    if n_lights is not None and frequency is not None:
        raise ConfigError("give the dome generator either n_lights or frequency, not both")
    if frequency is not None:
        pts = geodesic_sphere(frequency)
        el = _elevation_deg(pts)
        pts = pts[(el > max(min_elevation_deg, 0.0) + _ELEVATION_TOL_DEG)]
    else:
        n = 156 if n_lights is None else n_lights
        pts = _cut_to_count(n, min_elevation_deg)
    if azimuth_offset_deg:
        a = np.radians(azimuth_offset_deg)
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        pts = pts @ rot.T
    return _sorted(pts)


def _cut_to_count(n: int, min_elevation_deg: float) -> np.ndarray:
    near: list[str] = []
    for f in range(1, 17):
        pts = geodesic_sphere(f)
        el = _elevation_deg(pts)
        keep = el > max(min_elevation_deg, 0.0) + _ELEVATION_TOL_DEG
        rings = np.unique(np.round(el[keep], 6))
        # counts for every ring used as the lowest one, highest count first
        counts = [(int((el >= ring - _ELEVATION_TOL_DEG).sum()), ring) for ring in rings]
        for count, ring in counts:
            if count == n:
                return pts[el >= ring - _ELEVATION_TOL_DEG]
        below = [c for c, _ in counts if c < n]
        above = [c for c, _ in counts if c > n]
        if below and above:
            near.append(f"{max(below)} or {min(above)} at frequency {f}")
    raise ConfigError(
        f"no geodesic dome (frequency ≤ 16, elevation ≥ {min_elevation_deg:g}°) has exactly "
        f"{n} lights; nearest: {'; '.join(near[:3]) or 'none'}; pick one of those or list "
        "directions explicitly"
    )


def solid_angles_sr(directions: np.ndarray, *, hemisphere: bool = True) -> np.ndarray:
    """Solid angle (sr) of each light's spherical Voronoi cell.

    With ``hemisphere`` the cells cover the upper hemisphere only (sum 2π): the lights are
    mirrored below the horizon so that the horizon is a cell boundary. Otherwise they tile the
    whole sphere (sum 4π).

    Raises
    ------
    ConfigError
        If two lights coincide, or (hemisphere) a light is not above the horizon.
    """
    from scipy.spatial import SphericalVoronoi

    d = np.asarray(directions, dtype=float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    if hemisphere:
        if np.any(d[:, 2] <= 1e-9):
            raise ConfigError(
                "dome lights must lie above the horizon (z > 0) for hemisphere cells"
            )
        d = np.vstack([d, d * np.array([1.0, 1.0, -1.0])])
    if np.linalg.matrix_rank(d) < 3:
        raise ConfigError(
            "dome lights (with their mirror images) lie on one great circle, so their cells "
            "are undefined; spread the lights over the dome"
        )
    try:
        sv = SphericalVoronoi(d, radius=1.0, center=np.zeros(3))
    except ValueError as exc:
        raise ConfigError(
            f"cannot compute the dome's light cells ({exc}); remove duplicate lights"
        ) from None
    areas = sv.calculate_areas()
    return areas[: len(directions)] if hemisphere else areas


@dataclass(frozen=True)
class Dome:
    """Lights of a light stage, in the sample frame.

    Attributes
    ----------
    directions:
        Unit vectors (N, 3) from the sample towards each light (normal +z).
    solid_angles_sr:
        Solid angle (sr) each light stands for (Voronoi cell), summing to 2π.
    radius_m:
        Distance from the sample to the lights (m), if known.
    """

    directions: np.ndarray
    solid_angles_sr: np.ndarray
    radius_m: float | None = None

    def __len__(self) -> int:
        return len(self.directions)

    @property
    def elevation_deg(self) -> np.ndarray:
        """Elevation of each light above the horizon (deg)."""
        return _elevation_deg(self.directions)

    @property
    def zenith_deg(self) -> np.ndarray:
        """Angle of each light from the normal, θ (deg)."""
        return 90.0 - self.elevation_deg

    @property
    def azimuth_deg(self) -> np.ndarray:
        """Azimuth of each light, φ in [0, 360) from +x towards +y (deg)."""
        return _azimuth_deg(self.directions)


def _float_rows(value: object, field: str, columns: int, what: str) -> np.ndarray:
    """``value`` as a non-empty (N, columns) float array; ConfigError naming ``field`` if not."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{field} must be a list of {what}") from None
    if a.ndim != 2 or a.shape[1] != columns or len(a) == 0:
        raise ConfigError(f"{field} must be a non-empty list of {what}, got {a.shape}")
    return a


def _directions_from_list(value: object, field: str) -> np.ndarray:
    d = _float_rows(value, field, 3, "[x, y, z] triples")
    norm = np.linalg.norm(d, axis=1)
    bad = np.flatnonzero(~np.isfinite(norm) | (norm == 0))
    if bad.size:
        raise ConfigError(f"{field}[{bad[0]}] is not a non-zero finite vector; fix that light")
    return d / norm[:, None]


def _directions_from_angles(value: object, field: str) -> np.ndarray:
    a = _float_rows(value, field, 2, "[zenith_deg, azimuth_deg] pairs")
    th, ph = np.radians(a[:, 0]), np.radians(a[:, 1])
    return np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


_KEYS = {
    "generator",
    "n_lights",
    "frequency",
    "min_elevation_deg",
    "azimuth_offset_deg",
    "directions",
    "angles_deg",
    "radius_m",
}


def load_dome(config: Mapping[str, object], where: str = "dome") -> Dome:
    """A :class:`Dome` from rig-file data (the ``[dome]`` table).

    Exactly one source of directions:

    * ``generator = "geodesic"`` with ``n_lights`` (default 156) or ``frequency``, and
      optional ``min_elevation_deg``, ``azimuth_offset_deg``;
    * ``directions = [[x, y, z], …]`` (normalised; sample frame, normal +z);
    * ``angles_deg = [[zenith_deg, azimuth_deg], …]``.

    Optional ``radius_m``. Lights must lie above the horizon and be distinct.

    Raises
    ------
    ConfigError
        Naming the offending field.
    """
    unknown = set(config) - _KEYS
    if unknown:
        raise ConfigError(f"{where} has unknown keys {sorted(unknown)}; remove or rename them")
    sources = [k for k in ("generator", "directions", "angles_deg") if k in config]
    if len(sources) != 1:
        raise ConfigError(
            f"{where} needs exactly one of generator, directions, angles_deg (got "
            f"{', '.join(sources) or 'none'})"
        )
    source = sources[0]
    if source == "generator":
        if config["generator"] != "geodesic":
            raise ConfigError(f"{where}.generator {config['generator']!r} is unknown; use 'geodesic'")
        try:
            directions = geodesic_directions(
                None if config.get("n_lights") is None else int(config["n_lights"]),  # type: ignore[call-overload]
                frequency=None if config.get("frequency") is None else int(config["frequency"]),  # type: ignore[call-overload]
                min_elevation_deg=float(config.get("min_elevation_deg", 0.0)),  # type: ignore[arg-type]
                azimuth_offset_deg=float(config.get("azimuth_offset_deg", 0.0)),  # type: ignore[arg-type]
            )
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: bad geodesic generator settings ({exc})") from None
    else:
        extra = {"n_lights", "frequency", "min_elevation_deg", "azimuth_offset_deg"} & set(config)
        if extra:
            raise ConfigError(f"{where}: {sorted(extra)} apply to the generator only; remove them")
        field = f"{where}.{source}"
        parse = _directions_from_list if source == "directions" else _directions_from_angles
        directions = parse(config[source], field)
        below = np.flatnonzero(directions[:, 2] <= 1e-9)
        if below.size:
            raise ConfigError(
                f"{field}[{below[0]}] is not above the horizon (z ≤ 0); dome lights need z > 0"
            )
    radius = config.get("radius_m")
    if radius is not None and not (isinstance(radius, int | float) and radius > 0):
        raise ConfigError(f"{where}.radius_m must be a positive number (m), got {radius!r}")
    return Dome(
        directions=directions,
        solid_angles_sr=solid_angles_sr(directions),
        radius_m=None if radius is None else float(radius),
    )


def nearest_light(dome: Dome, direction: Sequence[float]) -> int:
    """Index of the dome light closest to ``direction`` (any non-zero vector)."""
    d = np.asarray(direction, dtype=float)
    return int(np.argmax(dome.directions @ (d / np.linalg.norm(d))))
