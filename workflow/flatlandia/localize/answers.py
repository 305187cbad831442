"""An answer as JSON values: the pose and its matches (:func:`answer_pose`), its status and
probability (:func:`answer_status`), why a query got no pose (:func:`no_pose_reason`), the text
(:func:`dumps`).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from flatlandia.classes import CLASSES
from flatlandia.localize.gps_fixes import far
from flatlandia.localize.object_map import ObjectMap, metres_to_map
from flatlandia.localize.query_files import MIN_OBJECTS, Query
from flatlandia.vocabulary import AMBIGUOUS, ANSWERED, NO_POSE


def answer_pose(m: ObjectMap, sol, unit: float, rows: np.ndarray, q: Query) -> dict:
    """A solution's pose and matches as JSON values (``rows``: the map rows it searched)."""
    theta = math.degrees(math.atan2(math.sin(sol.theta), math.cos(sol.theta)))
    lon, lat = m.lonlat_of(np.array([sol.x, sol.y]))
    matches = []
    for k, c in sol.inliers:
        row = int(rows[c])
        match = {
            "query_object": int(k),
            "obj_idx": int(m.obj_idx[row]),
            "class": CLASSES[int(m.cls[row])],
            "lon": float(m.lonlat[row, 0]) if m.lonlat is not None else None,
            "lat": float(m.lonlat[row, 1]) if m.lonlat is not None else None,
        }
        match.update(m.object_place(row))
        matches.append(match)
    return {
        "lon": lon,
        "lat": lat,
        "x_m": float(sol.x),
        "y_m": float(sol.y),
        "heading_deg": float((90.0 - theta) % 360.0) if lon is not None else None,  # north: the frame's +y
        "theta_deg": float(theta),
        "scale": float(sol.scale) / unit,
        **m.place(sol.x, sol.y),
        "matches": matches,
    }


def no_pose_reason(m: ObjectMap, cls, rows: np.ndarray, gps=None) -> str:
    """Why a query (``cls``: its objects' classes; None: a sequence) got no pose. With a fix, the fix
    is named when it ruled out every place (no map object within its 4 sigma, or too few of the
    query's classes near it), so that a fix 262 m off, or with lon/lat swapped, says so."""
    usable = int(np.isin(cls, m.cls[rows]).sum()) if cls is not None and len(rows) else 0
    n = len(cls) if cls is not None else 0
    if gps is None:
        if usable < MIN_OBJECTS:
            return f"only {usable} of the query's {n} objects have a class among the {len(rows)} map objects searched"
        return "no pose explains the query's objects on the map objects searched"
    lon, lat, sigma = (float(v) for v in gps[:3])
    gate = 4.0 * sigma
    where = f"of the fix at {lon}, {lat}"
    ask = "is the fix right? lon/lat swapped?"
    d = metres_to_map(m, lon, lat)
    if d is not None and d > gate:
        return f"no pose: no map object within 4 sigma ({gate:g} m) {where} (the nearest is {far(d)} away); {ask}"
    if cls is not None and usable < MIN_OBJECTS:
        return (
            f"no pose: only {usable} of the query's {n} objects have a class among the {len(rows)} map objects "
            f"within reach {where} (4 sigma, {gate:g} m, plus what a camera sees); {ask}"
        )
    return f"no pose within 4 sigma ({gate:g} m) {where} explains the objects on the map; {ask}"


def probability_of(sol) -> float | None:
    """A pose's probability of being within (5 m, 5 deg), None where it has none."""
    p = float(sol.probability)
    return p if math.isfinite(p) else None


def answer_status(best, threshold: float) -> dict:
    """``status`` and ``probability`` of an answer: ``no pose`` (probability 0) without a pose,
    ``ok`` when the pose's calibrated probability of being within (5 m, 5 deg) is at least
    ``threshold`` (``solver.answer_probability``), else ``ambiguous``: the alternatives, each with
    its probability, say where else the camera may be."""
    if best is None:
        return {"status": NO_POSE, "probability": 0.0}
    p = probability_of(best)
    return {"status": ANSWERED if p is None or p >= threshold else AMBIGUOUS, "probability": p}


def dumps(result: Any) -> str:
    """JSON text of an answer (non-finite numbers as null)."""

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(result), indent=1)
