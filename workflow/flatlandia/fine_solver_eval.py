"""Evaluate the bearing solver on the test split: per-query errors and a paper-style summary.

Proposals: ``gtbb`` (the paper's oracle: reference objects inside the box around the query's
objects and the true camera, enlarged 10%) and ``whole`` (the whole reference map, no oracle).
Errors are in true metres and degrees; ``paper_units_m`` gives the paper's convention
(local-map units x 215, see PAPER.md) for reading our rows against its tables.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from . import bearing_solver, geo, localmaps
from .recover import UNIT_DEG

THRESHOLDS = [(0.5, 2.0), (1.0, 5.0), (5.0, 10.0), (10.0, 20.0)]


def gtbb_proposal(ref_xy: np.ndarray, matched: list[int], cam_xy: np.ndarray, enlarge: float = 0.10) -> np.ndarray:
    pts = np.vstack([ref_xy[list(matched)], np.asarray(cam_xy, float)[None]])
    lo, hi = pts.min(0), pts.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * (1 + enlarge)
    return np.flatnonzero(np.all(np.abs(ref_xy - centre) <= half + 1e-9, axis=1))


def evaluate_scene(ref: pd.DataFrame, queries: pd.DataFrame, map_type: str, proposal: str,
                   solver_kwargs: dict, prior_xy: np.ndarray | None = None, progress=None) -> pd.DataFrame:
    """Solve every query; ``prior_xy`` (training cameras) constrains the whole-map setting."""
    ref_xy = ref[["x_m", "y_m"]].to_numpy()
    ref_cls = ref["class_id"].to_numpy()
    mpu = metres_per_unit(float(ref["lat"].mean()))
    rows = []
    items = list(queries.itertuples(index=False))
    for r in (progress(items) if progress else items):
        local = localmaps.xy(r.gt_local_xy_m if map_type == "gt" else r.depth_local_xy)
        cam = np.array([r.x_m, r.y_m])
        idx = gtbb_proposal(ref_xy, list(r.ref_idx), cam) if proposal == "gtbb" else np.arange(len(ref_xy))
        t0 = time.perf_counter()
        pose = bearing_solver.solve(local, np.asarray(r.classes), ref_xy[idx], ref_cls[idx], prior_xy=prior_xy,
                                    **solver_kwargs)
        dt = time.perf_counter() - t0
        solvable = sum(np.isin(ref_cls[idx], list(r.classes))) >= 3
        if pose is None:
            err_m, err_deg, conf = np.inf, 180.0, 0.0
        else:
            err_m = float(np.hypot(pose.x - r.x_m, pose.y - r.y_m))
            err_deg = float(abs(np.degrees(geo.wrap_angle(pose.theta - np.radians(r.theta_deg)))))
            conf = pose.confidence
        rows.append({"scene": r.scene, "token": r.token, "map_type": map_type, "proposal": proposal,
                     "n_objects": int(r.n_objects), "proposal_size": int(len(idx)), "solvable": bool(solvable),
                     "error_m": err_m, "error_deg": err_deg, "error_paper_units_m": err_m / mpu * 215.0,
                     "confidence": float(conf), "seconds": dt})
    return pd.DataFrame(rows)


def summarise(errors: pd.DataFrame) -> dict:
    """Median errors, % under the paper's thresholds, F%, gross errors, mean query time."""
    e = errors
    out = {"queries": len(e), "median_m": float(e["error_m"].median()), "median_deg": float(e["error_deg"].median())}
    for m, d in THRESHOLDS:
        out[f"pct_{m:g}m_{d:g}deg"] = float(100 * ((e["error_m"] < m) & (e["error_deg"] < d)).mean())
    out["failure_pct"] = float(100 * (~e["solvable"]).mean())
    out["gross_pct"] = float(100 * (e["error_m"] > 30).mean())
    out["mean_query_ms"] = float(1000 * e["seconds"].mean())
    out["median_paper_units_m"] = float(e["error_paper_units_m"].median())
    return out


def metres_per_unit(lat: float) -> float:
    """Mean metres per local-map unit at a latitude (the unit is isotropic in degrees)."""
    from .geo import MetricFrame

    mx, my = MetricFrame(0.0, lat).metres_per_degree()
    return UNIT_DEG * (mx + my) / 2
