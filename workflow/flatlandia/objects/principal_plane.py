"""Principal plane of a reconstruction (rule principal_plane).

- :func:`fit_plane` — open3d RANSAC plane + least-squares refit on the inliers (camera centres);
  :func:`fit_ground_plane` — Cauchy IRLS plane through the ground classes of a classified
  cloud (within 1.3 degrees of the published plane on all 12 class clouds, see its doc);
  :func:`plane_rotation` turns a normal into a 3x3 rotation onto the plane.
- :func:`normal_angle_deg` compares our normal with the published ``to_principal_plane``:
  published plane coordinates are ``X @ Rpp`` (docs/conventions.md), so the published normal is
  the third *column* of Rpp. Rpp is a reflection in 18 of 20 scenes and "up" is not known, so
  normals are compared up to sign.
- :func:`published_chain_transform` expresses the published SfM -> lon/lat chain as a metric
  2D scaled rigid transform (:class:`flatlandia.scaled_rigid.ScaledRigid`, fitted by pycolmap).

Degenerate input (fewer than 3 points, NaN, points on a line) raises :class:`InputError`
naming the source.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from flatlandia import config, geo
from flatlandia.objects import cloud
from flatlandia.plumbing.errors import InputError
from flatlandia.scaled_rigid import ScaledRigid, least_squares

# --------------------------------------------------------------------------- plane


@dataclass
class Plane:
    normal: np.ndarray  # unit (3,)
    point: np.ndarray  # a point on the plane (3,)
    inliers: np.ndarray  # bool (N,)
    rms: float  # RMS distance of the inliers (input units)


def _lsq_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares plane (centroid, unit normal): the smallest right singular vector."""
    c = points.mean(0)
    return c, np.linalg.svd(points - c, full_matrices=False)[2][2]


def fit_plane(
    points: np.ndarray,
    threshold: float | None = None,
    iterations: int = 500,
    seed: int = 0,
    source: str = "points",
    min_spread: float = 1e-3,
) -> Plane:
    """Robust plane: open3d's RANSAC (``segment_plane``, seeded, itself refitted by least squares
    on its inliers), then least squares (SVD) on the points within ``threshold`` of that plane
    (the returned inliers).

    ``threshold`` defaults to 2x the median absolute distance to a first least-squares plane
    (scale-free, so it works in SfM units). All ``iterations`` run (``probability=1``): open3d's
    early stop quits after ~20 samples on 49 camera centres, missing the best consensus, and its
    parallel loop then depends on thread timing; with every sample drawn the seed fixes the plane.
    """
    import open3d as o3d

    p = geo.check_points(points, 3, 3, source, "points")
    if geo.collinearity(p) < min_spread:
        raise InputError(
            source,
            f"degenerate plane: the {len(p)} points lie on a line (spread ratio {geo.collinearity(p):.2e} < {min_spread})",
        )
    if threshold is None:
        c, n0 = _lsq_plane(p)
        threshold = 2.0 * float(np.median(np.abs((p - c) @ n0))) + 1e-12
    o3d.utility.random.seed(seed)
    model, _ = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).segment_plane(
        threshold, 3, iterations, probability=1.0
    )
    inl = np.abs(p @ model[:3] + model[3]) <= threshold * np.linalg.norm(model[:3])
    c, n = _lsq_plane(p[inl] if inl.sum() >= 3 else p)
    rms = float(np.sqrt(np.mean(((p[inl] - c) @ n) ** 2))) if inl.any() else float("nan")
    return Plane(normal=n, point=c, inliers=inl, rms=rms)


#: Macro-classes lying on the street surface (markings, manholes; trash cans ride along in
#: the green colour and are down-weighted as outliers).
GROUND_CLASSES = ("marking_trash", "manhole")


def irls_plane(points: np.ndarray, scale: float, iterations: int = 20, source: str = "points") -> Plane:
    """Plane by iteratively reweighted least squares with Cauchy weights ``1 / (1 + (r/scale)^2)``.

    Why not RANSAC: ground-class points are few (tens to hundreds) and spread over several
    street levels, and a minimal-sample consensus locks onto whichever slab is densest (up to
    85 degrees off on the published clouds), while plain least squares follows kerbs and trash
    cans. Soft Cauchy weights with a scale of a few metres keep the whole street surface and
    fade the far outliers. ``scale`` is in the points' units; inliers are points within it.
    """
    p = geo.check_points(points, 3, 3, source, "points")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be positive, got {scale}")
    if geo.collinearity(p) < 1e-3:
        raise InputError(
            source, f"degenerate plane: the {len(p)} points lie on a line (spread ratio {geo.collinearity(p):.2e})"
        )
    w = np.ones(len(p))
    for _ in range(iterations):
        c = (w[:, None] * p).sum(0) / w.sum()
        n = np.linalg.svd((p - c) * np.sqrt(w)[:, None], full_matrices=False)[2][2]
        r = (p - c) @ n
        w = 1.0 / (1.0 + (r / scale) ** 2)
    inl = np.abs(r) <= scale
    rms = float(np.sqrt(np.mean(r[inl] ** 2))) if inl.any() else float("nan")
    return Plane(normal=n / np.linalg.norm(n), point=c, inliers=inl, rms=rms)


@config.settings("objects.principal_plane", frozen=True)
class PlaneConfig:
    """Settings of rule principal_plane: the config section ``objects.principal_plane`` (each key is
    described in config/README.md, ``objects.principal_plane.*``); :func:`fit_ground_plane` takes
    its defaults from here."""


_PLANE = PlaneConfig()


def fit_ground_plane(
    points: np.ndarray,
    labels: np.ndarray,
    metres_per_unit: float,
    ground_classes: tuple[str, ...] = GROUND_CLASSES,
    min_ground_points: int = _PLANE.min_ground_points,
    ground_scale_m: float = _PLANE.ground_scale_m,
    fallback_scale_m: float = _PLANE.fallback_scale_m,
    source: str = "cloud",
) -> tuple[Plane, str]:
    """Principal plane of a classified cloud -> (plane, which points were used).

    The published ``to_principal_plane`` is the street plane: on the 12 class clouds a Cauchy
    IRLS plane (:func:`irls_plane`, scale ``ground_scale_m``) through the ground-class points
    is within 1.3 degrees of it, whereas a plane through all points is 2-55 degrees off
    (facades and trees dominate). With fewer than ``min_ground_points`` ground points, the
    plane goes through all classified points with a tight scale (``fallback_scale_m``): signs,
    poles and lights stand along the street at similar heights. Lengths are in metres.
    """
    pts = np.asarray(points, float)
    labels = np.asarray(labels, dtype=object).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) != len(labels):
        raise InputError(source, f"points must be (N, 3) with one label each, got {pts.shape} and {labels.shape}")
    if not (np.isfinite(metres_per_unit) and metres_per_unit > 0):
        raise InputError(source, f"metres per SfM unit must be positive, got {metres_per_unit}")
    ground = np.isin(labels, list(ground_classes))
    if ground.sum() >= min_ground_points:
        return irls_plane(pts[ground], ground_scale_m / metres_per_unit, source=source), "ground classes"
    fg = labels != ""
    if fg.sum() < 3:
        raise InputError(source, f"only {int(fg.sum())} classified points: no plane can be fitted")
    return irls_plane(pts[fg], fallback_scale_m / metres_per_unit, source=source), "all classified points"


def plane_rotation(normal: np.ndarray, in_plane_hint: np.ndarray | None = None) -> np.ndarray:
    """Rotation (det +1) in the published row convention: ``X @ R`` has the normal as 3rd axis."""
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    h = np.array([1.0, 0, 0]) if in_plane_hint is None else np.asarray(in_plane_hint, float)
    if abs(h @ n) > 0.9:
        h = np.array([0, 1.0, 0]) if abs(n[1]) < 0.9 else np.array([0, 0, 1.0])
    x = h - (h @ n) * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    return np.column_stack([x, y, n])


def published_normal(rpp: np.ndarray) -> np.ndarray:
    """Normal of the published principal plane: third column of ``to_principal_plane``."""
    r = np.asarray(rpp, float)
    return r[:, 2] / np.linalg.norm(r[:, 2])


def normal_angle_deg(n1: np.ndarray, n2: np.ndarray) -> float:
    """Angle between two plane normals, up to sign (0..90 degrees)."""
    a, b = np.asarray(n1, float), np.asarray(n2, float)
    c = abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, 0.0, 1.0))))


# --------------------------------------------------------------------------- the published chain


def project_to_plane(points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Plane coordinates (N, 2) of 3D points in the row convention ``X @ R``."""
    return (np.asarray(points, float) @ np.asarray(rotation, float))[:, :2]


def published_chain_transform(transformations: dict, frame: geo.MetricFrame, samples: np.ndarray) -> ScaledRigid:
    """The published SfM->lon/lat chain expressed as a metric 2D scaled rigid transform from published plane
    coordinates to ``frame`` (fitted on ``samples``, exact up to the projection's curvature)."""
    rpp = np.asarray(transformations["to_principal_plane"], float)
    xy = frame.to_xy(geo.sfm_to_lonlat(samples, transformations))
    ok = np.isfinite(xy).all(1) & (np.linalg.norm(xy, axis=1) < 1e5)  # far outliers leave the projection
    if ok.sum() < 3:
        raise ValueError("fewer than 3 sample points project into the metric frame")
    return least_squares(project_to_plane(samples[ok], rpp), xy[ok], allow_reflection=True)


# --------------------------------------------------------------------------- rule principal_plane


def published_plane_report(
    scene: str,
    points: np.ndarray,
    labels: np.ndarray,
    transformations: dict,
    max_points: int = _PLANE.max_points,
    min_ground_points: int = _PLANE.min_ground_points,
    ground_scale_m: float = _PLANE.ground_scale_m,
    fallback_scale_m: float = _PLANE.fallback_scale_m,
    source: str = "cloud",
) -> dict:
    """Rule principal_plane's record of a published scene: our street plane of its class cloud
    (:func:`fit_ground_plane`) against the published ``to_principal_plane`` (angle, reflections)
    and the published SfM -> map chain as a metric 2D transform (:func:`published_chain_transform`,
    fitted on every ``len(points) // max_points``-th point in a frame on their median)."""
    pts = np.asarray(points, float)
    step = max(1, len(pts) // int(max_points))
    mpu = cloud.metres_per_unit(transformations)
    plane, plane_points = fit_ground_plane(
        pts,
        labels,
        mpu,
        min_ground_points=int(min_ground_points),
        ground_scale_m=float(ground_scale_m),
        fallback_scale_m=float(fallback_scale_m),
        source=source,
    )
    rpp = np.asarray(transformations["to_principal_plane"], float)
    r2 = np.asarray(transformations["to_mapillary"]["rotation"], float)
    pub_n = published_normal(rpp)
    # frame on the median point: clouds hold far outliers that a bounding-box centre would follow
    med = np.median(geo.sfm_to_lonlat(pts[::step], transformations), axis=0)
    frame = geo.MetricFrame(lon0=round(float(med[0]), 7), lat0=round(float(med[1]), 7))
    chain = published_chain_transform(transformations, frame, pts[::step])
    return {
        "scene": scene,
        "method": "published chain (no camera GPS in the published data)",
        "plane_source": f"class point cloud, {plane_points} (Cauchy IRLS)",
        "plane_normal": plane.normal.tolist(),
        "plane_inlier_fraction": float(plane.inliers.mean()),
        "published_normal": pub_n.tolist(),
        "plane_angle_deg": normal_angle_deg(plane.normal, pub_n),
        "published_rpp_is_reflection": bool(np.linalg.det(rpp) < 0),
        "published_r2_is_reflection": bool(np.linalg.det(r2) < 0),
        "metres_per_sfm_unit": mpu,
        "chain_metric_scale_m_per_unit": chain.scale,
        "chain_rotation_deg": chain.angle_deg(),
        "chain_is_reflection": chain.reflection,
        "our_plane_rotation": plane_rotation(plane.normal).tolist(),
    }
