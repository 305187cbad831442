"""Reference maps as tables, GeoJSON (EPSG:4326, opens in QGIS) and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import figures, geo
from flatlandia.io import atomic_path, write_text


def reference_table(
    scene: str, lonlat: np.ndarray, classes: np.ndarray, labels: list[str], frame: geo.MetricFrame
) -> pd.DataFrame:
    """One row per object: its index in the published map, class, lon/lat and metric x/y."""
    xy = frame.to_xy(lonlat)
    return pd.DataFrame(
        {
            "scene": scene,
            "obj_idx": np.arange(len(lonlat), dtype=np.int64),
            "class_id": np.asarray(classes, dtype=np.int64),
            "class_label": [labels[c] for c in classes],
            "lon": lonlat[:, 0],
            "lat": lonlat[:, 1],
            "x_m": xy[:, 0],
            "y_m": xy[:, 1],
        }
    )


def frame_metadata(scene: str, frame: geo.MetricFrame) -> dict:
    return {
        "scene": scene,
        "crs": frame.proj4,
        "lon0": frame.lon0,
        "lat0": frame.lat0,
        "axes": "x east, y north, metres (transverse Mercator centred on the scene)",
    }


def geojson(ref: pd.DataFrame, meta: dict) -> dict:
    """A FeatureCollection of the objects as points in EPSG:4326 (RFC 7946 order lon, lat)."""
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": [float(r.lon), float(r.lat)]},
            "properties": {
                "obj_idx": int(r.obj_idx),
                "class_id": int(r.class_id),
                "class_label": r.class_label,
                "x_m": float(r.x_m),
                "y_m": float(r.y_m),
            },
        }
        for r in ref.itertuples(index=False)
    ]
    return {
        "type": "FeatureCollection",
        "name": f"flatlandia_scene_{meta['scene']}",
        "flatlandia": meta,
        "features": feats,
    }


def write_geojson(ref: pd.DataFrame, meta: dict, path: str | Path) -> None:
    write_text(json.dumps(geojson(ref, meta), indent=1) + "\n", path)


def write_geoparquet(ref: pd.DataFrame, meta: dict, path: str | Path) -> None:
    """GeoParquet (EPSG:4326 points) with the frame metadata; opens in QGIS and geopandas."""
    import geopandas as gpd

    gdf = gpd.GeoDataFrame(ref.copy(), geometry=gpd.points_from_xy(ref["lon"], ref["lat"]), crs="EPSG:4326")
    with atomic_path(path) as tmp:
        gdf.to_parquet(tmp, index=False)
        # keep the metric frame next to the geo metadata
        import pyarrow.parquet as pq

        table = pq.read_table(tmp)
        md = dict(table.schema.metadata or {})
        md[b"flatlandia"] = json.dumps(meta, sort_keys=True).encode()
        pq.write_table(table.replace_schema_metadata(md), tmp)


def plot_reference_map(ref: pd.DataFrame, queries: pd.DataFrame | None, path: str | Path, title: str) -> None:
    """Objects coloured by class, query cameras with heading arrows, in metres."""
    plt = figures.pyplot()

    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    cmap = plt.get_cmap("tab20")
    for k, (label, grp) in enumerate(ref.groupby("class_label", sort=True)):
        ax.scatter(
            grp["x_m"],
            grp["y_m"],
            s=22,
            color=cmap(k % 20),
            label=f"{label} ({len(grp)})",
            edgecolor="k",
            linewidth=0.3,
            zorder=3,
        )
    if queries is not None and len(queries):
        th = np.radians(queries["theta_deg"].to_numpy())
        colours = queries["split"].map({"train": "0.55", "val": "tab:blue", "test": "tab:red"})
        ax.quiver(
            queries["x_m"],
            queries["y_m"],
            np.cos(th),
            np.sin(th),
            color=colours.tolist(),
            angles="xy",
            scale_units="xy",
            scale=0.25,
            width=0.003,
            zorder=2,
        )
        ax.scatter([], [], marker=r"$\rightarrow$", color="0.55", label="query camera (train)")
        ax.scatter([], [], marker=r"$\rightarrow$", color="tab:red", label="query camera (test)")
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
