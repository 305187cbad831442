"""Images scenes: align a SfM model with geotagged cameras to GPS (rule gps_alignment).

Street-level crowd photos are taken upright, so the cameras' image-down axes agree on gravity
even when the camera centres lie on one line (a walk along a street) and a plane fit through
them is degenerate. The ground plane is therefore the plane normal to the cameras' mean "up"
axis; camera centres projected on it are aligned to their GPS positions by a robust scaled
rigid transform (:func:`ransac_scaled_rigid`: Umeyama inside RANSAC; no reflection: the up
axis fixes handedness). The result is an affine map of SfM points onto the metric map,
``xy = A @ X + b`` (A: 2x3), as :mod:`flatlandia.images.image_queries` expects. Altitude is
kept as a 1D fit along the up axis.

- :func:`ransac_scaled_rigid` — Umeyama (closed-form scaled rigid transform) inside RANSAC with a
  seeded rng, 2D or 3D, optional reflection (a plane's sign is arbitrary, so a mirrored map is
  possible) and an optional heading term (camera headings must agree with the rotation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from flatlandia import geo
from flatlandia.errors import InputError

# --------------------------------------------------------------------------- scaled rigid transforms


@dataclass
class ScaledRigid:
    """Rotation, uniform scale and translation:
    dst ~= scale * src @ rotation.T + translation (rotation may be a reflection if allowed)."""

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


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True, allow_reflection: bool = False) -> ScaledRigid:
    """Closed-form least-squares scaled rigid transform (Umeyama 1991) taking src onto dst (N, d)."""
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
    return ScaledRigid(scale=s, rotation=r, translation=t)


def _heading_residual(sim: ScaledRigid, src_heading: np.ndarray, dst_heading: np.ndarray) -> np.ndarray:
    """|angle| (rad) between mapped source headings and target headings (2D only)."""
    v = np.column_stack([np.cos(src_heading), np.sin(src_heading)]) @ sim.rotation.T
    pred = np.arctan2(v[:, 1], v[:, 0])
    return np.abs(geo.wrap_angle(pred - dst_heading))


def ransac_scaled_rigid(
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
) -> ScaledRigid:
    """Robust scaled rigid transform src -> dst: minimal-sample Umeyama hypotheses scored by inlier count
    (ties: lower residual sum), refit on the inliers. ``threshold`` is in dst units (metres).

    With headings (radians, CCW, same frames as the points), an inlier must also agree in
    heading within ``heading_threshold_deg``; a reflection flips headings too.
    """
    src_d = np.asarray(src, float)
    dim = src_d.shape[1] if src_d.ndim == 2 else 0
    if dim not in (2, 3):
        raise InputError(source, f"source points must be (N, 2) or (N, 3), got shape {src_d.shape}")
    src = geo.check_points(src, dim, 3, source, "cameras with GPS")
    dst = geo.check_points(dst, dim, 3, source, "GPS positions")
    if len(src) != len(dst):
        raise InputError(source, f"{len(src)} camera positions but {len(dst)} GPS positions")
    if geo.collinearity(src) < 1e-9 or np.ptp(src, axis=0).max() == 0:
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

    def score(sim: ScaledRigid) -> tuple[np.ndarray, np.ndarray]:
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
        raise InputError(source, f"no scaled rigid transform explains at least {k} cameras within {threshold} m")
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


def _reflected(sim: ScaledRigid) -> ScaledRigid:
    """Fold a mirror of the source's y axis into a transform fitted on mirrored source points."""
    r = sim.rotation @ np.diag([1.0, -1.0])
    return ScaledRigid(scale=sim.scale, rotation=r, translation=sim.translation)


def transform_error(est: ScaledRigid, src: np.ndarray, true_dst: np.ndarray) -> dict:
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


# --------------------------------------------------------------------------- GPS alignment


def camera_up(rotations: np.ndarray, max_angle_deg: float = 30.0) -> np.ndarray:
    """World up direction from upright cameras: minus their mean image-down axis (rows 1 of R).

    ``rotations`` are cam_from_world (N, 3, 3). Cameras whose down axis is more than
    ``max_angle_deg`` off the first estimate (tilted shots) are left out of the second.
    """
    down = np.asarray(rotations, float).reshape(-1, 3, 3)[:, 1, :]
    m = down.mean(0)
    if np.linalg.norm(m) < 1e-9:
        raise ValueError("the cameras' down axes cancel out: no common up direction")
    m /= np.linalg.norm(m)
    keep = down @ m > np.cos(np.radians(max_angle_deg))
    if keep.sum() >= 1:
        m = down[keep].mean(0)
        m /= np.linalg.norm(m)
    return -m


def plane_basis(up: np.ndarray) -> np.ndarray:
    """Rows e1, e2 of an orthonormal basis of the plane normal to ``up`` with e1 x e2 = up.

    Right-handed in-plane axes keep counter-clockwise angles counter-clockwise on the map.
    """
    up = np.asarray(up, float) / np.linalg.norm(up)
    helper = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = np.cross(helper, up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return np.vstack([e1, e2])


def compass_to_theta(heading_deg: np.ndarray) -> np.ndarray:
    """Compass heading (degrees clockwise from north) -> radians counter-clockwise from east."""
    return np.radians(90.0 - np.asarray(heading_deg, float))


def fit_gps_alignment(
    centres: np.ndarray,
    rotations: np.ndarray,
    lonlat: np.ndarray,
    altitude: np.ndarray | None = None,
    compass_deg: np.ndarray | None = None,
    threshold_m: float = 15.0,
    iterations: int = 2000,
    seed: int = 0,
    use_heading: bool = False,
    heading_threshold_deg: float = 45.0,
    source: str = "cameras",
) -> dict:
    """Align SfM cameras to their GPS positions; returns the affine map and its residuals.

    ``centres`` (N, 3) and ``rotations`` (N, 3, 3, cam_from_world) of the cameras that have GPS
    ``lonlat`` (N, 2). ``threshold_m`` is the RANSAC inlier distance (consumer GPS errs by
    5-10 m). The compass is compared with the aligned viewing directions and only used in the
    fit when ``use_heading`` (crowd compasses are often wrong).
    """
    centres = np.asarray(centres, float).reshape(-1, 3)
    lonlat = np.asarray(lonlat, float).reshape(-1, 2)
    if len(centres) != len(lonlat):
        raise InputError(source, f"{len(centres)} cameras but {len(lonlat)} GPS positions")
    ok = np.isfinite(centres).all(1) & np.isfinite(lonlat).all(1)
    if ok.sum() < 3:
        raise InputError(
            source,
            f"only {int(ok.sum())} registered camera(s) with GPS: at least 3 are needed to align the model to GPS",
        )
    rot = np.asarray(rotations, float).reshape(-1, 3, 3)
    up = camera_up(rot[ok])
    P = plane_basis(up)
    frame = geo.frame_for(lonlat[ok])
    dst = frame.to_xy(lonlat[ok])
    src = centres[ok] @ P.T
    view_dirs = rot[ok][:, 2, :] @ P.T  # camera +z axes in the plane
    src_theta = np.arctan2(view_dirs[:, 1], view_dirs[:, 0])
    dst_theta = None
    if compass_deg is not None:
        comp = np.asarray(compass_deg, float).reshape(-1)[ok]
        dst_theta = compass_to_theta(comp)
    heading_fit = use_heading and dst_theta is not None and np.isfinite(dst_theta).all()
    sim = ransac_scaled_rigid(
        src,
        dst,
        threshold=threshold_m,
        iterations=iterations,
        seed=seed,
        allow_reflection=False,
        src_heading=src_theta if heading_fit else None,
        dst_heading=dst_theta if heading_fit else None,
        heading_threshold_deg=heading_threshold_deg,
        source=source,
    )
    A = sim.scale * sim.rotation @ P
    b = np.asarray(sim.translation, float)
    res = np.full(len(centres), np.nan)
    res[ok] = np.linalg.norm(centres[ok] @ A.T + b - dst, axis=1)
    inl = np.zeros(len(centres), bool)
    inl[np.flatnonzero(ok)[sim.inliers]] = True
    out = {
        "mode": "gps",
        "A": A.tolist(),
        "b": b.tolist(),
        "up": up.tolist(),
        "frame_lon0": frame.lon0,
        "frame_lat0": frame.lat0,
        "crs": frame.proj4,
        "unit": "m",
        "metres_per_sfm_unit": float(sim.scale),
        "rotation_deg": sim.angle_deg(),
        "cameras_with_gps": int(ok.sum()),
        "inliers": int(inl.sum()),
        "median_residual_m": float(np.nanmedian(res)),
        "max_residual_m": float(np.nanmax(res)),
        "inlier_median_residual_m": float(np.median(res[inl])) if inl.any() else float("nan"),
        "residuals_m": [None if not np.isfinite(r) else float(r) for r in res],
        "inlier_mask": inl.tolist(),
        "heading_used": bool(heading_fit),
    }
    if dst_theta is not None:
        mapped = np.arctan2(*(view_dirs @ sim.rotation.T)[:, ::-1].T)
        diff = np.degrees(np.abs(geo.wrap_angle(mapped - dst_theta)))
        out["compass_median_diff_deg"] = float(np.nanmedian(diff))
        out["compass_within_30deg"] = float(np.mean(diff[np.isfinite(diff)] < 30)) if np.isfinite(diff).any() else 0.0
    if altitude is not None:
        alt = np.asarray(altitude, float).reshape(-1)[ok]
        h = sim.scale * (centres[ok] @ up)
        good = np.isfinite(alt)
        if good.any():
            off = float(np.median(alt[good] - h[good]))
            out["altitude_offset_m"] = off
            out["altitude_median_residual_m"] = float(np.median(np.abs(alt[good] - h[good] - off)))
    return out


def local_frame(centres: np.ndarray, rotations: np.ndarray, unit_m: float = 1.0) -> dict:
    """The map of a scene without GPS (``images.align.mode: none``): the SfM ground plane.

    x/y lie on the plane normal to the cameras' mean up axis (right-handed, so angles keep their
    sense), origin at the cameras' centroid, in SfM units times ``unit_m`` (the metres a user
    assumes per SfM unit; 1 = the SfM unit itself). No lon/lat: ``crs`` and the frame origin are
    None. Same keys as :func:`fit_gps_alignment`, so objects and queries are built alike.
    """
    centres = np.asarray(centres, float).reshape(-1, 3)
    if len(centres) == 0:
        raise ValueError("no registered camera: no ground plane")
    up = camera_up(np.asarray(rotations, float).reshape(-1, 3, 3))
    A = float(unit_m) * plane_basis(up)
    b = -A @ centres.mean(0)
    return {
        "mode": "none",
        "A": A.tolist(),
        "b": b.tolist(),
        "up": up.tolist(),
        "frame_lon0": None,
        "frame_lat0": None,
        "crs": None,
        "unit": "SfM unit" if float(unit_m) == 1.0 else f"SfM unit x {float(unit_m):g} (assumed metres)",
        "metres_per_sfm_unit": float(unit_m),
        "cameras_with_gps": 0,
        "inliers": 0,
    }


def is_local(alignment: dict) -> bool:
    """A local-frame map (no GPS): x/y in SfM units, no lon/lat."""
    return alignment.get("mode") == "none"


def map_points(alignment: dict, X: np.ndarray) -> np.ndarray:
    """SfM points (N, 3) -> map xy (N, 2): metres of the GPS frame, or the local frame's unit."""
    return np.asarray(X, float).reshape(-1, 3) @ np.asarray(alignment["A"]).T + np.asarray(alignment["b"])


def frame_of(alignment: dict) -> geo.MetricFrame | None:
    """The metric frame of a GPS-aligned map; None for a local-frame map."""
    if is_local(alignment):
        return None
    return geo.MetricFrame(lon0=alignment["frame_lon0"], lat0=alignment["frame_lat0"])


def to_lonlat(alignment: dict, xy: np.ndarray) -> np.ndarray:
    """Map xy -> lon/lat (N, 2); NaN in a local frame, which has no geographic position."""
    frame = frame_of(alignment)
    xy = np.asarray(xy, float).reshape(-1, 2)
    return frame.to_lonlat(xy) if frame is not None and len(xy) else np.full((len(xy), 2), np.nan)


def gps_outliers(
    centres: np.ndarray,
    rotations: np.ndarray,
    lonlat: np.ndarray,
    max_residual_m: float,
    threshold_m: float = 15.0,
    seed: int = 0,
) -> np.ndarray:
    """Cameras the SfM put far from their own GPS fix once the model is aligned to GPS.

    Cameras without GPS are never flagged; with fewer than 3 geotagged cameras no alignment
    exists and nothing is flagged (the caller logs it).
    """
    lonlat = np.asarray(lonlat, float).reshape(-1, 2)
    if np.isfinite(lonlat).all(1).sum() < 3:
        return np.zeros(len(lonlat), bool)
    al = fit_gps_alignment(centres, rotations, lonlat, threshold_m=threshold_m, seed=seed)
    res = np.array([np.nan if r is None else r for r in al["residuals_m"]], float)
    return np.nan_to_num(res, nan=0.0) > max_residual_m
