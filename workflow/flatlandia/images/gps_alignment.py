"""Images scenes: align a SfM model with geotagged cameras to GPS (rule gps_alignment).

Street-level crowd photos are taken upright, so the cameras' image-down axes agree on gravity
even when the camera centres lie on one line (a walk along a street) and a plane fit through
them is degenerate. The ground plane is therefore the plane normal to the cameras' mean "up"
axis (:func:`camera_up`, :func:`plane_basis`: ours, pycolmap has no such step); camera centres
projected on it are aligned to their GPS positions by pycolmap's robust similarity
(:func:`flatlandia.scaled_rigid.ransac_scaled_rigid`: LO-RANSAC, no reflection: the up axis fixes
handedness). The compass is compared with the aligned viewing directions (ours too). The result
is an affine map of SfM points onto the metric map, ``xy = A @ X + b`` (A: 2x3), as
:mod:`flatlandia.images.image_queries` expects. Altitude is kept as a 1D fit along the up axis.
Without GPS (``images.align.mode: none``), :func:`local_frame` keeps the SfM frame on that plane.
"""

from __future__ import annotations

import numpy as np

from flatlandia import config, geo
from flatlandia.plumbing.errors import InputError
from flatlandia.scaled_rigid import ransac_scaled_rigid

#: Defaults: the `images.align` section of workflow/schemas/config.schema.yaml.
_ALIGN = config.section_defaults("images.align")

# --------------------------------------------------------------------------- the mode of each scene

#: the scene sheet's optional column that sets one images scene's ``images.align.mode``, so that scenes
#: with and without GPS are built in one run (empty: the config's mode)
SHEET_COLUMN = "align"


def align_modes() -> list[str]:
    """The values of ``images.align.mode`` (the schema's enum: gps, none)."""
    return list(config.schema()["properties"]["images"]["properties"]["align"]["properties"]["mode"]["enum"])


def sheet_align_problem(sheet) -> str | None:
    """What is wrong with the scene sheet's ``align`` column, as 'line N, column align: ...' (the
    header is line 1), or None: a cell neither empty nor a mode (:func:`align_modes`), or a mode on a
    published scene (whose map is the published one: nothing is aligned)."""
    if SHEET_COLUMN not in sheet.columns:
        return None
    from flatlandia.plumbing.validate import shown

    modes = align_modes()
    for i, (cell, source, scene) in enumerate(zip(sheet[SHEET_COLUMN], sheet["source"], sheet["scene"])):
        where = f"line {i + 2}, column {SHEET_COLUMN}"
        if cell == "":
            continue
        if cell not in modes:
            return f"{where}: {shown(cell)} is not {', '.join(modes)} or empty (empty: the config's images.align.mode)"
        if source != "images":
            return (
                f"{where}: {shown(cell)} on published scene {shown(scene)}: only an images scene is aligned "
                "(leave the cell empty)"
            )
    return None


def scene_mode(cell: str, default: str) -> str:
    """A scene's ``images.align.mode``: its sheet cell (checked by :func:`sheet_align_problem`), else
    the config's ``default``."""
    return cell or default


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
    threshold_m: float = _ALIGN["threshold_m"],
    iterations: int = _ALIGN["iterations"],
    seed: int = 0,
    use_heading: bool = _ALIGN["use_heading"],
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
        "inlier_median_residual_m": float(np.median(res[inl])) if inl.any() else None,
        "residuals_m": [None if not np.isfinite(r) else float(r) for r in res],
        "inlier_mask": inl.tolist(),
        "heading_used": bool(heading_fit),
    }
    # the compass against the aligned viewing directions, over the cameras that give a heading
    # (None, JSON null, when none does: photos placed by a metadata.csv without a heading column)
    given = np.isfinite(dst_theta) if dst_theta is not None else np.zeros(len(src), bool)
    out["compass_cameras"] = int(given.sum())
    out["compass_median_diff_deg"] = out["compass_within_30deg"] = None
    if given.any():
        mapped = np.arctan2(*(view_dirs[given] @ sim.rotation.T)[:, ::-1].T)
        diff = np.degrees(np.abs(geo.wrap_angle(mapped - dst_theta[given])))
        out["compass_median_diff_deg"] = float(np.median(diff))
        out["compass_within_30deg"] = float(np.mean(diff < 30))
    if altitude is not None:
        alt = np.asarray(altitude, float).reshape(-1)[ok]
        h = sim.scale * (centres[ok] @ up)
        good = np.isfinite(alt)
        if good.any():
            off = float(np.median(alt[good] - h[good]))
            out["altitude_offset_m"] = off
            out["altitude_median_residual_m"] = float(np.median(np.abs(alt[good] - h[good] - off)))
    return out


def align_camera_table(cams, views: dict, params: dict, seed: int, source: str, log=None) -> tuple:
    """Rule gps_alignment in ``gps`` mode: the cameras of ``cams`` (a table with name, lat, lon, alt,
    heading; NaN where not given) that have a GPS position, aligned to it. ``views`` maps each
    name to its SfM view (``centre``, ``R``); ``params`` is the ``images.align`` section.
    Returns (the cameras used, :func:`fit_gps_alignment`'s result)."""
    has_gps = cams["lat"].notna() & cams["lon"].notna()
    cams = cams[has_gps].reset_index(drop=True)
    heading = cams["heading"].to_numpy(float) if "heading" in cams else np.full(len(cams), np.nan)
    out = fit_gps_alignment(
        np.array([views[n].centre for n in cams["name"]]).reshape(-1, 3),
        np.array([views[n].R for n in cams["name"]]).reshape(-1, 3, 3),
        cams[["lon", "lat"]].to_numpy(float),
        altitude=cams["alt"].to_numpy(float) if "alt" in cams else None,
        compass_deg=heading,
        threshold_m=float(params["threshold_m"]),
        iterations=int(params["iterations"]),
        seed=int(seed),
        use_heading=bool(params["use_heading"]),
        source=source,
    )
    if log is not None and not out["compass_cameras"]:
        log.info("no compass headings were given (EXIF or metadata.csv): no compass comparison")
    if log is not None and bool(params["use_heading"]) and not out["heading_used"]:
        log.info(
            "images.align.use_heading is set, but only %d of %d cameras give a heading: aligned without it",
            out["compass_cameras"],
            len(cams),
        )
    return cams, out


def local_frame(centres: np.ndarray, rotations: np.ndarray, unit_m: float = _ALIGN["unit_m"]) -> dict:
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


def gps_outliers(
    centres: np.ndarray,
    rotations: np.ndarray,
    lonlat: np.ndarray,
    max_residual_m: float,
    threshold_m: float = _ALIGN["threshold_m"],
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


def scene_alignment(scene: str, rec, cameras, params: dict, seed: int, source: str = "cameras", log=None) -> dict:
    """Rule gps_alignment: an images scene's SfM model ``rec`` (pycolmap) -> the map's ground plane.

    ``cameras`` is rule sfm's camera table (name, lat, lon, alt, heading), of which the registered
    ones are used, sorted by name; ``params`` is the ``images.align`` section: mode ``gps``
    (:func:`align_camera_table`: metres, lon/lat) or ``none`` (:func:`local_frame`: the SfM ground
    plane in ``unit_m``, no lon/lat). Returns the record written to alignment.json: scene, method,
    the cameras used and the alignment (affine map ``A``, ``b``, residuals, frame)."""
    from flatlandia.images import views

    views = {v.name: v for v in views.views_from_colmap(rec)}
    cams = cameras[cameras["name"].isin(views)].sort_values("name").reset_index(drop=True)
    if params["mode"] == "none":
        out = local_frame(
            np.array([views[n].centre for n in cams["name"]]).reshape(-1, 3),
            np.array([views[n].R for n in cams["name"]]).reshape(-1, 3, 3),
            unit_m=float(params["unit_m"]),
        )
        method = "camera up axes -> ground plane; local frame, no GPS (images.align.mode: none)"
    else:
        cams, out = align_camera_table(cams, views, params, seed, source, log)
        method = "camera up axes -> ground plane; RANSAC similarity to GPS"
    return {"scene": scene, "method": method, "cameras": cams["name"].tolist(), **out}
