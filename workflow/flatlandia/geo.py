"""Coordinates: the published SfM -> lon/lat chain, local metric frames, 2D rigid motions.

Conventions (measured on the data, see docs/conventions.md):
- lon/lat are degrees (EPSG:4326). The published chain maps SfM points to lon/lat with an
  isotropic scale *in degrees*; we treat the resulting lon/lat as the geographic truth.
- A scene's metric frame is a transverse Mercator projection centred on the scene
  (x = east, y = north, metres). Its PROJ string is stored with every map.
- 2D headings are counter-clockwise angles from +x (east) of the camera's viewing axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from flatlandia.plumbing.errors import InputError

if TYPE_CHECKING:  # pyproj loads when a frame projects: the learned models' code needs none of it
    from pyproj import Transformer

#: Published Flatlandia constant: one local-map unit is TO_FLATLANDIA / 2 degrees.
TO_FLATLANDIA = 0.0033780547666424354
#: Degrees per local-map unit (docs/conventions.md, "Local maps").
UNIT_DEG = TO_FLATLANDIA / 2.0
#: Fewest objects a 2D pose is found and checked with (a 2-point fit and a third to check it): of a
#: query, a published local map, a solvable proposal. The schema's ``images.min_objects`` may not go
#: below it (its ``minimum``; tests/test_defaults_once.py checks they agree).
MIN_OBJECTS = 3


@dataclass(frozen=True)
class MetricFrame:
    """A local transverse Mercator frame around (lon0, lat0): x east, y north, metres."""

    lon0: float
    lat0: float

    @property
    def proj4(self) -> str:
        return (
            f"+proj=tmerc +lat_0={self.lat0:.10f} +lon_0={self.lon0:.10f} +k=1 "
            "+x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
        )

    def _forward(self) -> Transformer:
        from pyproj import CRS, Transformer

        return Transformer.from_crs(CRS.from_epsg(4326), CRS.from_proj4(self.proj4), always_xy=True)

    def _inverse(self) -> Transformer:
        from pyproj import CRS, Transformer

        return Transformer.from_crs(CRS.from_proj4(self.proj4), CRS.from_epsg(4326), always_xy=True)

    def to_xy(self, lonlat: np.ndarray) -> np.ndarray:
        """(N, 2) lon/lat degrees -> (N, 2) metres."""
        lonlat = np.asarray(lonlat, dtype=float).reshape(-1, 2)
        x, y = self._forward().transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([x, y])

    def to_lonlat(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) metres -> (N, 2) lon/lat degrees."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        lon, lat = self._inverse().transform(xy[:, 0], xy[:, 1])
        return np.column_stack([lon, lat])

    def metres_per_degree(self) -> tuple[float, float]:
        """Local scale (metres per degree of lon, metres per degree of lat) at the origin."""
        eps = 1e-4
        pts = self.to_xy(
            np.array(
                [
                    [self.lon0 - eps, self.lat0],
                    [self.lon0 + eps, self.lat0],
                    [self.lon0, self.lat0 - eps],
                    [self.lon0, self.lat0 + eps],
                ]
            )
        )
        return (float(np.linalg.norm(pts[1] - pts[0]) / (2 * eps)), float(np.linalg.norm(pts[3] - pts[2]) / (2 * eps)))

    def heading_to_metric(self, theta_deg_space: np.ndarray) -> np.ndarray:
        """Turn a direction angle measured in isotropic lon/lat degrees into the metric frame.

        Degrees of longitude are shorter than degrees of latitude, so a direction drawn in
        lon/lat space points elsewhere in metres (up to ~20 degrees off at 50 N).
        """
        mx, my = self.metres_per_degree()
        theta = np.asarray(theta_deg_space, dtype=float)
        return np.arctan2(my * np.sin(theta), mx * np.cos(theta))


def frame_for(lonlat: np.ndarray) -> MetricFrame:
    """The metric frame of a scene: centred on the bounding-box centre of its objects."""
    lonlat = np.asarray(lonlat, dtype=float).reshape(-1, 2)
    lo, hi = lonlat.min(axis=0), lonlat.max(axis=0)
    c = (lo + hi) / 2.0
    return MetricFrame(lon0=round(float(c[0]), 7), lat0=round(float(c[1]), 7))


def rot2(theta: float | np.ndarray) -> np.ndarray:
    """2x2 (or ...x2x2) counter-clockwise rotation matrix."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def wrap_angle(theta: np.ndarray | float) -> np.ndarray | float:
    """Wrap radians into [-pi, pi)."""
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi


def pose_errors(x, y, theta_rad, gt_x, gt_y, gt_theta_rad):
    """Position error (m) and absolute wrapped heading error (deg) of poses against the truth;
    vectorised."""
    e_m = np.hypot(np.asarray(x, float) - gt_x, np.asarray(y, float) - gt_y)
    e_deg = np.abs(np.degrees(wrap_angle(np.asarray(theta_rad, float) - np.asarray(gt_theta_rad, float))))
    return e_m, e_deg


def world_to_local(points: np.ndarray, cam_xy: np.ndarray, theta: float) -> np.ndarray:
    """Express world points in a camera frame: camera at origin, looking along +x, +y left."""
    return (np.asarray(points, float) - np.asarray(cam_xy, float)) @ rot2(theta)


def local_to_world(local: np.ndarray, cam_xy: np.ndarray, theta: float) -> np.ndarray:
    """Inverse of :func:`world_to_local`."""
    return np.asarray(local, float) @ rot2(theta).T + np.asarray(cam_xy, float)


def sfm_to_lonlat(points: np.ndarray, transformations: dict) -> np.ndarray:
    """Push SfM points (N, 3) through the published chain to lon/lat (N, 2).

    lonlat = s * R2[:2, :2] @ (Rpp.T @ X)[:2] + t[:2]; in row form X @ Rpp. Rpp and R2 may be
    reflections, so no axis is assumed to point up.
    """
    rpp = np.asarray(transformations["to_principal_plane"], float)
    tm = transformations["to_mapillary"]
    r2 = np.asarray(tm["rotation"], float)
    s = float(tm["scaling_factor_sfm_to_gps"])
    t = np.asarray(tm["translation"], float).reshape(-1)[:2]
    plane = np.asarray(points, float).reshape(-1, 3) @ rpp
    return s * plane[:, :2] @ r2[:2, :2].T + t


def rigid_fit_2d(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares rotation + translation (no scale, no reflection) taking src onto dst.

    Returns (theta, t) with dst ~= src @ rot2(theta).T + t.
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    cs, cd = src.mean(0), dst.mean(0)
    a, b = src - cs, dst - cd
    num = np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    den = np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    theta = float(np.arctan2(num, den))
    t = cd - cs @ rot2(theta).T
    return theta, t


# --------------------------------------------------------------------------- point checks


def check_points(points: np.ndarray, dim: int, min_n: int, source: str, what: str) -> np.ndarray:
    """``points`` as a finite (N, dim) float array of at least ``min_n`` rows, else :class:`InputError`."""
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != dim:
        raise InputError(source, f"{what} must be an (N, {dim}) array, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(source, f"{int((~np.isfinite(p).all(1)).sum())} {what} with NaN/inf coordinates")
    if len(p) < min_n:
        raise InputError(source, f"need at least {min_n} {what}, got {len(p)}")
    return p


def collinearity(p: np.ndarray) -> float:
    """Second singular value over the first of the centred points (0 = all on a line).

    Measured on the 90% of points nearest the median, so a few far outliers cannot make a
    real cloud look like a line.
    """
    d = np.linalg.norm(p - np.median(p, axis=0), axis=1)
    q = p[d <= np.quantile(d, 0.9)] if len(p) >= 10 else p
    sv = np.linalg.svd(q - q.mean(0), compute_uv=False)
    return float(sv[1] / sv[0]) if sv[0] > 0 else 0.0


# An images scene's alignment record (rule gps_alignment, flatlandia.images.gps_alignment): its
# SfM points -> map xy (metres of a GPS frame, or a local frame's unit without GPS) -> lon/lat.


def alignment_is_local(alignment: dict) -> bool:
    """A local-frame map (no GPS): x/y in SfM units, no lon/lat."""
    return alignment.get("mode") == "none"


def alignment_points(alignment: dict, X: np.ndarray) -> np.ndarray:
    """SfM points (N, 3) -> map xy (N, 2): metres of the GPS frame, or the local frame's unit."""
    return np.asarray(X, float).reshape(-1, 3) @ np.asarray(alignment["A"]).T + np.asarray(alignment["b"])


def alignment_frame(alignment: dict) -> MetricFrame | None:
    """The metric frame of a GPS-aligned map; None for a local-frame map."""
    if alignment_is_local(alignment):
        return None
    return MetricFrame(lon0=alignment["frame_lon0"], lat0=alignment["frame_lat0"])


def alignment_lonlat(alignment: dict, xy: np.ndarray) -> np.ndarray:
    """Map xy -> lon/lat (N, 2); NaN in a local frame, which has no geographic position."""
    frame = alignment_frame(alignment)
    xy = np.asarray(xy, float).reshape(-1, 2)
    return frame.to_lonlat(xy) if frame is not None and len(xy) else np.full((len(xy), 2), np.nan)
