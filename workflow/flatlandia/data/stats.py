"""Dataset statistics: the paper's Table 2, recomputed per scene, per city and overall."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
from scipy.spatial import ConvexHull

from flatlandia import geo, paper


def hull_area_m2(xy: np.ndarray) -> float:
    xy = np.asarray(xy, float)
    if len(xy) < 3:
        return 0.0
    try:
        return float(ConvexHull(xy).volume)  # in 2D, volume is the area
    except Exception:  # collinear points
        return 0.0


def map_kb(ref: pd.DataFrame) -> float:
    """Size of the map in the benchmark's compact form: [[lon, lat], class] per object."""
    payload = [[[float(a), float(b)], int(c)] for a, b, c in zip(ref["lon"], ref["lat"], ref["class_id"])]
    return len(json.dumps(payload, separators=(",", ":")).encode()) / 1000.0


def scene_stats(scene: str, city: str, ref: pd.DataFrame, queries: pd.DataFrame, n_images: int | None) -> dict:
    """One row of per-scene statistics (areas in km2 from the scene's metric frame)."""
    area = hull_area_m2(ref[["x_m", "y_m"]].to_numpy())
    cov = hull_area_m2(np.vstack([ref[["x_m", "y_m"]].to_numpy(), queries[["x_m", "y_m"]].to_numpy()]))
    return {
        "scene": scene,
        "city": city,
        "objects": len(ref),
        "queries": len(queries),
        "images": float(n_images) if n_images is not None else np.nan,
        "classes_in_map": int(ref["class_id"].nunique()),
        "area_km2": area / 1e6,
        "covered_km2": cov / 1e6,
        "kb_per_map": map_kb(ref),
        "queries_gt4": int((queries["n_objects"] > 4).sum()),
        "objects_per_query": float(queries["n_objects"].mean()),
    }


def city_table(per_scene: pd.DataFrame, union_km2: dict[str, float]) -> pd.DataFrame:
    """Per-city means (and the union of scene areas) with the paper's figures beside ours."""
    rows = []
    groups = list(per_scene.groupby("city", sort=True)) + [("all", per_scene)]
    for city, g in groups:
        published = paper.TABLE2.get(city, {})
        rows.append(
            {
                "city": city,
                "scenes": len(g),
                "area_km2": g["area_km2"].mean(),
                "kb_per_map": g["kb_per_map"].mean(),
                "images": g["images"].mean(),
                "objects": g["objects"].mean(),
                "queries": g["queries"].mean(),
                "total_objects": int(g["objects"].sum()),
                "total_queries": int(g["queries"].sum()),
                "union_area_km2": union_km2.get(city, np.nan),
                "density_per_1000m2": g["objects"].sum() / (g["area_km2"].sum() * 1000.0),
                "paper_scenes": published.get("scenes", np.nan),
                "paper_objects": published.get("objects", np.nan),
                "paper_queries": published.get("queries", np.nan),
                "paper_area_km2": published.get("area_km2", np.nan),
                "paper_kb_per_map": published.get("kb_per_map", np.nan),
                "paper_images": published.get("images", np.nan),
            }
        )
    df = pd.DataFrame(rows)
    floats = [c for c in df.columns if c.startswith("paper_")] + ["images"]
    return df.astype({c: float for c in floats})


def union_area_km2(lonlat_by_scene: dict[str, np.ndarray]) -> float:
    """Area covered by the union of several scenes' object hulls (overlapping scenes count once)."""
    from shapely.geometry import MultiPoint
    from shapely.ops import unary_union

    pts = np.vstack(list(lonlat_by_scene.values()))
    frame = geo.frame_for(pts)
    hulls = [MultiPoint(frame.to_xy(ll)).convex_hull for ll in lonlat_by_scene.values()]
    return float(unary_union(hulls).area) / 1e6
