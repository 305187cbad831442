"""Local maps in metres: metric GT maps, depth maps carried into the metric camera frame.

Axis convention of every local map we write: camera at the origin, looking along +x, +y to
its left (counter-clockwise), units in metres of the scene's metric frame. ``theta`` is the
heading of the camera's +x axis, counter-clockwise from east, in that metric frame.

Depth local maps are published with an arbitrary per-query scale (depth/GT ratio 0.001-0.01)
in the same degree-unit frame as the GT maps. We carry them into the metric camera frame (so
their bearings are true bearings, see :func:`published_to_metric_frame`) and normalise each
so that the median object range is 1; the least-squares factor to the GT metric map is
stored separately as an *oracle* for analysis.
"""

from __future__ import annotations

import numpy as np

from flatlandia import geo


def metric_local_map(ref_xy: np.ndarray, cam_xy: np.ndarray, theta: float) -> np.ndarray:
    """The matched objects (metric frame) seen from the camera: (M, 2) metres."""
    return geo.world_to_local(ref_xy, cam_xy, theta)


def published_to_metric_frame(
    local: np.ndarray, theta_lonlat: float, theta_metric: float, metres_per_degree: tuple[float, float]
) -> np.ndarray:
    """A published local map (degree units, isotropic in lon/lat) in the metric camera frame.

    Published maps live in lon/lat degrees, where east-west is stretched by 1/cos(lat): their
    bearings are not the camera's true bearings. Undo it: camera frame -> lon/lat offsets ->
    metres -> metric camera frame. Applied to a GT map this gives the metric GT map (to within
    the projection's variation over the scene); applied to a depth map it keeps its shape up to
    the unknown scale, with true bearings.
    """
    offsets_deg = np.asarray(local, float) @ geo.rot2(theta_lonlat).T * geo.UNIT_DEG
    metres = offsets_deg * np.asarray(metres_per_degree, float)
    return metres @ geo.rot2(theta_metric)


def normalise_depth_map(depth: np.ndarray) -> tuple[np.ndarray, float]:
    """Scale a depth local map so its median object range is 1; returns (map, factor)."""
    depth = np.asarray(depth, float)
    med = float(np.median(np.linalg.norm(depth, axis=1)))
    if not np.isfinite(med) or med <= 0:
        return depth.copy(), float("nan")
    return depth / med, 1.0 / med


def oracle_scale(src: np.ndarray, dst: np.ndarray) -> float:
    """Least-squares s minimising ||s*src - dst|| (both in the camera frame)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    den = float(np.sum(src * src))
    return float(np.sum(src * dst) / den) if den > 0 else float("nan")


def xy(cell) -> np.ndarray:
    """A local-map cell (list of [x, y], or the array of arrays Parquet gives back) as (M, 2)."""
    return np.stack([np.asarray(p, dtype=float) for p in cell]).reshape(-1, 2)


#: local-map column of each map type in queries.parquet
LOCAL_MAP_COLUMNS = {"gt": "gt_local_xy_m", "depth": "depth_local_xy"}


def local_map(row, map_type: str) -> np.ndarray:
    """A query's local map of one type (GT in metres, depth in normalised units) as (M, 2); ``row``
    is a DataFrame row, a dict or an ``itertuples`` tuple."""
    if map_type not in LOCAL_MAP_COLUMNS:
        raise ValueError(f"map_type must be 'gt' or 'depth', got {map_type!r}")
    column = LOCAL_MAP_COLUMNS[map_type]
    return xy(getattr(row, column) if isinstance(row, tuple) else row[column])
