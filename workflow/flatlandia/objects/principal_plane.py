"""Alignment of a reconstruction: principal plane, and a robust similarity to GPS.

- :func:`fit_plane` — RANSAC plane + least-squares refit on the inliers (camera centres);
  :func:`fit_ground_plane` — Cauchy IRLS plane through the ground classes of a classified
  cloud (within 1.3 degrees of the published plane on all 12 class clouds, see its doc);
  :func:`plane_rotation` turns a normal into a 3x3 rotation onto the plane.
- :func:`normal_angle_deg` compares our normal with the published ``to_principal_plane``:
  published plane coordinates are ``X @ Rpp`` (DATA.md), so the published normal is the third
  *column* of Rpp. Rpp is a reflection in 18 of 20 scenes and "up" is not known, so normals are
  compared up to sign.
- :func:`ransac_similarity` — Umeyama (closed-form similarity) inside RANSAC with a seeded rng,
  2D or 3D, optional reflection (the plane's sign is arbitrary, so a mirrored map is possible)
  and an optional heading term (camera headings must agree with the rotation).

Degenerate input (fewer than 3 points, NaN, points on a line) raises :class:`InputError`
naming the source.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flatlandia import geo
from flatlandia.errors import InputError


def _check_points(points: np.ndarray, dim: int, min_n: int, source: str, what: str) -> np.ndarray:
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != dim:
        raise InputError(source, f"{what} must be an (N, {dim}) array, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(source, f"{int((~np.isfinite(p).all(1)).sum())} {what} with NaN/inf coordinates")
    if len(p) < min_n:
        raise InputError(source, f"need at least {min_n} {what}, got {len(p)}")
    return p


def _collinearity(p: np.ndarray) -> float:
    """Second singular value over the first of the centred points (0 = all on a line).

    Measured on the 90% of points nearest the median, so a few far outliers cannot make a
    real cloud look like a line.
    """
    d = np.linalg.norm(p - np.median(p, axis=0), axis=1)
    q = p[d <= np.quantile(d, 0.9)] if len(p) >= 10 else p
    sv = np.linalg.svd(q - q.mean(0), compute_uv=False)
    return float(sv[1] / sv[0]) if sv[0] > 0 else 0.0


# --------------------------------------------------------------------------- plane


@dataclass
class Plane:
    normal: np.ndarray  # unit (3,)
    point: np.ndarray  # a point on the plane (3,)
    inliers: np.ndarray  # bool (N,)
    rms: float  # RMS distance of the inliers (input units)


def fit_plane(
    points: np.ndarray,
    threshold: float | None = None,
    iterations: int = 500,
    seed: int = 0,
    source: str = "points",
    min_spread: float = 1e-3,
) -> Plane:
    """Robust plane: RANSAC on 3-point samples, then least squares (SVD) on the inliers.

    ``threshold`` defaults to 2x the median absolute distance to a first least-squares plane
    (scale-free, so it works in SfM units).
    """
    p = _check_points(points, 3, 3, source, "points")
    if _collinearity(p) < min_spread:
        raise InputError(
            source,
            f"degenerate plane: the {len(p)} points lie on a line (spread ratio {_collinearity(p):.2e} < {min_spread})",
        )
    c = p.mean(0)
    n0 = np.linalg.svd(p - c, full_matrices=False)[2][2]
    if threshold is None:
        threshold = 2.0 * float(np.median(np.abs((p - c) @ n0))) + 1e-12
    rng = np.random.default_rng(seed)
    best = np.abs((p - c) @ n0) <= threshold
    for _ in range(iterations if len(p) > 3 else 0):
        s = p[rng.choice(len(p), 3, replace=False)]
        n = np.cross(s[1] - s[0], s[2] - s[0])
        nn = np.linalg.norm(n)
        if nn < 1e-12:
            continue
        inl = np.abs((p - s[0]) @ (n / nn)) <= threshold
        if inl.sum() > best.sum():
            best = inl
    q = p[best] if best.sum() >= 3 else p
    c = q.mean(0)
    n = np.linalg.svd(q - c, full_matrices=False)[2][2]
    inl = np.abs((p - c) @ n) <= threshold
    if inl.sum() >= 3:
        c = p[inl].mean(0)
        n = np.linalg.svd(p[inl] - c, full_matrices=False)[2][2]
    rms = float(np.sqrt(np.mean(((p[inl] - c) @ n) ** 2))) if inl.any() else float("nan")
    return Plane(normal=n / np.linalg.norm(n), point=c, inliers=inl, rms=rms)


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
    p = _check_points(points, 3, 3, source, "points")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be positive, got {scale}")
    if _collinearity(p) < 1e-3:
        raise InputError(
            source, f"degenerate plane: the {len(p)} points lie on a line (spread ratio {_collinearity(p):.2e})"
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


def fit_ground_plane(
    points: np.ndarray,
    labels: np.ndarray,
    metres_per_unit: float,
    ground_classes: tuple[str, ...] = GROUND_CLASSES,
    min_ground_points: int = 25,
    ground_scale_m: float = 8.0,
    fallback_scale_m: float = 1.0,
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


# --------------------------------------------------------------------------- similarity


@dataclass
class Similarity:
    """dst ~= scale * src @ rotation.T + translation (rotation may be a reflection if allowed)."""

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def apply(self, src: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(src, float) @ self.rotation.T + self.translation

    @property
    def reflection(self) -> bool:
        return bool(np.linalg.det(self.rotation) < 0)

    def angle_deg(self) -> float:
        """Rotation angle of a 2D transform (of its proper part for a reflection)."""
        r = self.rotation.copy()
        if self.reflection:
            r[:, 1] *= -1
        return float(np.degrees(np.arctan2(r[1, 0], r[0, 0])))


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True, allow_reflection: bool = False) -> Similarity:
    """Closed-form least-squares similarity (Umeyama 1991) taking src onto dst (N, d)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    d = src.shape[1]
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    cov = b.T @ a / len(src)
    u, sv, vt = np.linalg.svd(cov)
    sgn = np.ones(d)
    if not allow_reflection and np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[-1] = -1
    r = u @ np.diag(sgn) @ vt
    var = (a**2).sum() / len(src)
    s = float((sv * sgn).sum() / var) if with_scale and var > 0 else 1.0
    t = md - s * ms @ r.T
    return Similarity(scale=s, rotation=r, translation=t)


def _heading_residual(sim: Similarity, src_heading: np.ndarray, dst_heading: np.ndarray) -> np.ndarray:
    """|angle| (rad) between mapped source headings and target headings (2D only)."""
    v = np.column_stack([np.cos(src_heading), np.sin(src_heading)]) @ sim.rotation.T
    pred = np.arctan2(v[:, 1], v[:, 0])
    return np.abs(geo.wrap_angle(pred - dst_heading))


def ransac_similarity(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float = 10.0,
    iterations: int = 1000,
    seed: int = 0,
    allow_reflection: bool = True,
    src_heading: np.ndarray | None = None,
    dst_heading: np.ndarray | None = None,
    heading_threshold_deg: float = 30.0,
    source: str = "cameras",
) -> Similarity:
    """Robust similarity src -> dst: minimal-sample Umeyama hypotheses scored by inlier count
    (ties: lower residual sum), refit on the inliers. ``threshold`` is in dst units (metres).

    With headings (radians, CCW, same frames as the points), an inlier must also agree in
    heading within ``heading_threshold_deg``; a reflection flips headings too.
    """
    src_d = np.asarray(src, float)
    dim = src_d.shape[1] if src_d.ndim == 2 else 0
    if dim not in (2, 3):
        raise InputError(source, f"source points must be (N, 2) or (N, 3), got shape {src_d.shape}")
    src = _check_points(src, dim, 3, source, "cameras with GPS")
    dst = _check_points(dst, dim, 3, source, "GPS positions")
    if len(src) != len(dst):
        raise InputError(source, f"{len(src)} camera positions but {len(dst)} GPS positions")
    if _collinearity(src) < 1e-9 or np.ptp(src, axis=0).max() == 0:
        raise InputError(source, "degenerate: all camera positions coincide or lie on one point")
    use_heading = src_heading is not None and dst_heading is not None
    if use_heading:
        if dim != 2:
            raise ValueError("the heading term is defined for 2D alignments only")
        src_heading, dst_heading = np.asarray(src_heading, float), np.asarray(dst_heading, float)
        if src_heading.shape != (len(src),) or dst_heading.shape != (len(src),):
            raise InputError(source, "one heading per camera is needed on both sides")
    h_thr = np.radians(heading_threshold_deg)
    rng = np.random.default_rng(seed)
    k = 2 if dim == 2 else 3

    def score(sim: Similarity) -> tuple[np.ndarray, np.ndarray]:
        res = np.linalg.norm(sim.apply(src) - dst, axis=1)
        inl = res <= threshold
        if use_heading:
            inl &= _heading_residual(sim, src_heading, dst_heading) <= h_thr
        return inl, res

    best, best_key = None, (-1, np.inf)
    refl_options = (False, True) if allow_reflection else (False,)
    for _ in range(iterations):
        idx = rng.choice(len(src), k, replace=False)
        if np.linalg.norm(src[idx[1]] - src[idx[0]]) == 0:
            continue
        for refl in refl_options:
            if dim == 2:
                sim = (
                    umeyama(src[idx], dst[idx], allow_reflection=False)
                    if not refl
                    else _reflected(umeyama(src[idx] * [1, -1], dst[idx]))
                )
            else:
                sim = umeyama(src[idx], dst[idx], allow_reflection=refl)
            if not np.isfinite(sim.scale) or sim.scale <= 0:
                continue
            inl, res = score(sim)
            key = (int(inl.sum()), -float(np.minimum(res, threshold).sum()))
            if key > (best_key[0], -best_key[1]):
                best, best_key = sim, (key[0], -key[1])
    if best is None or best_key[0] < k:
        raise InputError(source, f"no similarity explains at least {k} cameras within {threshold} m")
    inl, _ = score(best)
    refl = best.reflection
    for _ in range(3):  # refit on inliers until stable
        if dim == 2 and refl:
            sim = _reflected(umeyama(src[inl] * [1, -1], dst[inl]))
        else:
            sim = umeyama(src[inl], dst[inl], allow_reflection=False)
        new_inl, res = score(sim)
        if new_inl.sum() < k:
            break
        best = sim
        if np.array_equal(new_inl, inl):
            break
        inl = new_inl
    inl, res = score(best)
    best.inliers, best.residuals = inl, res
    return best


def _reflected(sim: Similarity) -> Similarity:
    """Fold a mirror of the source's y axis into a similarity fitted on mirrored source points."""
    r = sim.rotation @ np.diag([1.0, -1.0])
    return Similarity(scale=sim.scale, rotation=r, translation=sim.translation)


def project_to_plane(points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Plane coordinates (N, 2) of 3D points in the row convention ``X @ R``."""
    return (np.asarray(points, float) @ np.asarray(rotation, float))[:, :2]


def published_chain_similarity(transformations: dict, frame: geo.MetricFrame, samples: np.ndarray) -> Similarity:
    """The published SfM->lon/lat chain expressed as a metric 2D similarity from published plane
    coordinates to ``frame`` (fitted on ``samples``, exact up to the projection's curvature)."""
    rpp = np.asarray(transformations["to_principal_plane"], float)
    xy = frame.to_xy(geo.sfm_to_lonlat(samples, transformations))
    ok = np.isfinite(xy).all(1) & (np.linalg.norm(xy, axis=1) < 1e5)  # far outliers leave the projection
    if ok.sum() < 3:
        raise ValueError("fewer than 3 sample points project into the metric frame")
    return umeyama(project_to_plane(samples[ok], rpp), xy[ok], allow_reflection=True)


def similarity_error(est: Similarity, src: np.ndarray, true_dst: np.ndarray) -> dict:
    """Errors of an estimated transform against the truth on given points (metres)."""
    e = np.linalg.norm(est.apply(src) - true_dst, axis=1)
    ref = umeyama(src, true_dst, allow_reflection=True)
    return {
        "median_m": float(np.median(e)),
        "max_m": float(e.max()),
        "rms_m": float(np.sqrt(np.mean(e**2))),
        "scale_ratio": float(est.scale / ref.scale),
        "rotation_deg": float(abs(geo.wrap_angle(np.radians(est.angle_deg() - ref.angle_deg()))) * 180 / np.pi),
        "reflection_correct": bool(est.reflection == ref.reflection),
    }
