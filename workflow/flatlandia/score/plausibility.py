"""What looks like a convention mixed up in a poses file (lon and lat swapped, radians for degrees,
another frame, poses outside their scene): warnings, not errors (:func:`plausibility` over the
file, :func:`row_plausibility` per row).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.plumbing.errors import InputError
from flatlandia.score.poses import FORMS, Poses, listing, shortened, to_metric
from flatlandia.score.scenes import BenchmarkScene

#: plausibility: a fix that makes the median error this many times smaller is reported ...
FAR_SMALLER = 5.0


#: ... when the median errors as given are at least this large (m, deg): a good method is never
#: suspected, and an honest poor one is not made 5 times better by a swap or a unit
IMPLAUSIBLE_M = 5.0


IMPLAUSIBLE_DEG = 20.0


#: metric positions this far from the truth (median) look like another frame (UTM, lon/lat...)
ANOTHER_FRAME_M = 10_000.0


def _truth(poses: Poses, scenes: dict[str, BenchmarkScene]) -> pd.DataFrame:
    """Each pose row's true pose (gx, gy, gtheta_deg)."""
    parts = []
    for s, b in scenes.items():
        q = b.queries[["token", "x_m", "y_m", "theta_deg"]].rename(
            columns={"x_m": "gx", "y_m": "gy", "theta_deg": "gtheta"}
        )
        parts.append(q.assign(scene=s, token=q["token"].astype(str)))
    truth = (
        pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["scene", "token", "gx", "gy", "gtheta"])
    )
    return poses.table.merge(truth, on=["scene", "token"], how="left")


#: a pose this far outside its scene (the box around its map objects and query cameras), metres, is
#: nowhere a method could have put it from that map
EXTENT_MARGIN_M = 500.0


def scene_extents(scenes: dict[str, BenchmarkScene]) -> dict[str, tuple[float, float, float, float]]:
    """Per scene the box (x0, y0, x1, y1) in its metric frame around its reference objects and every
    query camera, grown by :data:`EXTENT_MARGIN_M`: where a pose of that scene can be."""
    out = {}
    for s, b in scenes.items():
        xy = np.vstack(
            [
                b.ref[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2),
                b.queries[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2),
            ]
        )
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            lo, hi = xy.min(axis=0) - EXTENT_MARGIN_M, xy.max(axis=0) + EXTENT_MARGIN_M
            out[s] = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    return out


def _readings(t: pd.DataFrame, form: str, scenes: dict[str, BenchmarkScene], path) -> dict[str, tuple]:
    """The pose rows read the ways a file's units or order are mixed up: reason -> (x, y) per row
    in the scene frame (NaN where that reading gives no position)."""
    a, b = t["a"].to_numpy(float), t["b"].to_numpy(float)
    if form == "metric":
        ways = {
            "x_m, y_m look like kilometres (the columns are metres)": (a * 1000.0, b * 1000.0),
            "x_m and y_m look swapped (x_m is east, y_m north)": (b, a),
            "x_m, y_m look like kilometres and swapped": (b * 1000.0, a * 1000.0),
        }
        return ways
    ways = {
        "lon and lat look swapped (lon is longitude, lat latitude)": (b, a),
        "lon, lat look like radians (the columns are degrees)": (np.degrees(a), np.degrees(b)),
        "lon, lat look like radians and swapped": (np.degrees(b), np.degrees(a)),
    }
    out = {}
    for why, (la, lb) in ways.items():
        x, y = np.full(len(t), np.nan), np.full(len(t), np.nan)
        ok = (np.abs(la) <= 180) & (np.abs(lb) <= 90)
        for sc, rows in t[ok].groupby("scene", sort=False).indices.items():
            frame = scenes[sc].frame
            if frame is None:
                continue
            idx = np.flatnonzero(ok)[rows]
            with np.errstate(all="ignore"):
                xy = frame.to_xy(np.column_stack([la[idx], lb[idx]]))
            x[idx], y[idx] = xy[:, 0], xy[:, 1]
        out[why] = (x, y)
    return out


def row_plausibility(poses: Poses, scenes: dict[str, BenchmarkScene]) -> list[str]:
    """Pose by pose, against its scene (:func:`scene_extents`): a pose outside the scene's extent looks
    wrong, and so does one that a mixed-up unit or order (kilometres, x/y or lon/lat swapped, lon/lat
    in radians, :func:`_readings`) explains: as given it is where no method could have put it (outside
    the scene; for kilometres also within the scene shrunk 1000 times around its origin), and read
    that way it lies in the scene, closer to its truth. A wrong pose inside the scene is a method's
    error, not a mix-up, however near its swapped reading falls to the truth (a solver's pose on
    scene 10 was called swapped so); a whole file swapped inside its scenes is :func:`plausibility`'s
    median test. Some such rows: a warning naming them (returned); most of them (over half):
    InputError, the file is not scored."""
    t = _truth(poses, scenes)
    if not len(t):
        return []
    x, y = t["x_m"].to_numpy(float), t["y_m"].to_numpy(float)
    gx, gy = t["gx"].to_numpy(float), t["gy"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        err = np.hypot(x - gx, y - gy)
    box = scene_extents(scenes)
    ext = np.array([box.get(sc, (-np.inf, -np.inf, np.inf, np.inf)) for sc in t["scene"]], float).reshape(-1, 4)

    def inside(px, py, shrink: float = 1.0):
        with np.errstate(invalid="ignore"):
            return (
                (px >= ext[:, 0] / shrink)
                & (py >= ext[:, 1] / shrink)
                & (px <= ext[:, 2] / shrink)
                & (py <= ext[:, 3] / shrink)
            )

    outside = ~inside(x, y)
    at_origin = inside(x, y, 1000.0)  # where a pose in kilometres lands
    reason = np.array(["" for _ in range(len(t))], dtype=object)
    best = np.full(len(t), np.inf)
    for why, (rx, ry) in _readings(t, poses.form, scenes, poses.path).items():
        with np.errstate(invalid="ignore"):
            e = np.hypot(rx - gx, ry - gy)
            telling = (outside | at_origin) if "kilometres" in why else outside
            fixes = inside(rx, ry) & (e < err) & telling & (e < best)
        reason[fixes], best[fixes] = why, e[fixes]
    far = outside & (reason == "")
    with np.errstate(invalid="ignore"):
        km = np.hypot(
            np.maximum(ext[:, 0] - x, x - ext[:, 2]).clip(0), np.maximum(ext[:, 1] - y, y - ext[:, 3]).clip(0)
        )
    reason[far] = [f"{d / 1000:.4g} km outside the scene" for d in km[far]]
    wrong = np.flatnonzero(reason != "")
    if not len(wrong):
        return []
    name = Path(poses.path).name
    groups: dict[str, list[str]] = {}
    for i in wrong:
        why = "outside the scene" if far[i] else str(reason[i])
        detail = f" ({reason[i]})" if far[i] else ""
        label = f"{t['where'].iloc[i]} (scene {shortened(t['scene'].iloc[i])}, token {shortened(t['token'].iloc[i])}){detail}"
        groups.setdefault(why, []).append(label)
    what = f"{len(wrong)} of its {len(t)} poses look wrong for their scene: " + "; ".join(
        f"{why}: {listing(rows, 3)}" for why, rows in groups.items()
    )
    hint = (
        " (x_m, y_m: metres in the scene's own frame, transverse Mercator centred on the scene, lon0/lat0 in its "
        "reference map's metadata; lon, lat: degrees)"
    )
    if 2 * len(wrong) > len(t):
        raise InputError(poses.path, f"{what}{hint}; fix the file: nothing was scored")
    return [f"{name}: {what}{hint}; scored as given"]


def plausibility(poses: Poses, scenes: dict[str, BenchmarkScene], min_poses: int = 3) -> list[str]:
    """Warnings (text, not errors) where the poses look like a convention mixed up: swapping
    lon/lat (or x_m/y_m) gives far smaller position errors; reading the angles as radians (or as
    degrees converted twice), or as the other angle convention (compass heading vs counter-clockwise
    from east), gives far smaller heading errors; positions kilometres off (another frame)."""
    rows = row_plausibility(poses, scenes)  # most rows wrong: InputError
    t = _truth(poses, scenes)
    if len(t) < min_poses:
        return rows
    gt = t[["gx", "gy"]].to_numpy(float)
    g_theta = np.radians(t["gtheta"].to_numpy(float))
    x, y, theta = (t[c].to_numpy(float) for c in ("x_m", "y_m", "theta_deg"))
    e_m, e_deg = geo.pose_errors(x, y, np.radians(theta), gt[:, 0], gt[:, 1], g_theta)
    med_m, med_deg = float(np.median(e_m)), float(np.median(e_deg))
    out = list(rows)
    name = Path(poses.path).name
    cols = FORMS[poses.form]
    if med_m > IMPLAUSIBLE_M:
        swapped = t.assign(a=t["b"], b=t["a"])
        try:
            sx, sy, _ = to_metric(swapped, poses.form, scenes, poses.path)
        except InputError:
            sx = sy = np.full(len(t), np.nan)
        with np.errstate(invalid="ignore"):
            s_m = float(np.median(np.hypot(sx - gt[:, 0], sy - gt[:, 1])))
        if np.isfinite(s_m) and s_m * FAR_SMALLER < med_m:
            out.append(
                f"{name}: {cols[0]} and {cols[1]} look swapped: swapped, the median position error would be "
                f"{s_m:.2f} m instead of {med_m:.4g} m ({cols[0]} is {'longitude' if poses.form == 'geographic' else 'east'}, "
                f"{cols[1]} {'latitude' if poses.form == 'geographic' else 'north'})"
            )
        elif poses.form == "metric" and med_m > ANOTHER_FRAME_M:
            out.append(
                f"{name}: the positions are {med_m / 1000:.4g} km from the truth (median): x_m, y_m are metres in the "
                "scene's own frame (transverse Mercator centred on the scene, lon0/lat0 in its reference map's "
                "metadata), not UTM or lon/lat; for lon/lat give lon, lat, heading_deg instead"
            )
    if med_deg > IMPLAUSIBLE_DEG:
        angle = t["angle"].to_numpy(float)
        to_theta = (lambda v: 90.0 - v) if poses.form == "geographic" else (lambda v: v)
        other = "counter-clockwise from east (theta)" if poses.form == "geographic" else "a compass heading"
        # the unit mix-ups only where the values show it: radians within a turn of 2 pi, degrees
        # converted twice beyond a turn of 360
        turn = float(np.max(np.abs(angle)))
        fixes = [
            (np.degrees(angle), "radians (the column is degrees)", turn <= 2 * np.pi + 1e-6),
            (np.radians(angle), "degrees converted to degrees twice (read as radians)", turn > 360.0),
            (90.0 - angle, other, True),
        ]
        best = None
        for v, what, possible in fixes:
            if not possible:
                continue
            d = float(np.median(geo.pose_errors(x, y, np.radians(to_theta(v)), gt[:, 0], gt[:, 1], g_theta)[1]))
            if d * FAR_SMALLER < med_deg and (best is None or d < best[0]):
                best = (d, what)
        if best:
            out.append(
                f"{name}: the {cols[2]} values look like {best[1]}: read so, the median heading error would be "
                f"{best[0]:.2f} deg instead of {med_deg:.2f} deg ({cols[2]} is degrees, "
                + ("clockwise from north" if poses.form == "geographic" else "counter-clockwise from east")
                + ")"
            )
    return out
