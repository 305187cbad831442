"""Reference maps as tables, GeoJSON (EPSG:4326, opens in QGIS) and plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo
from flatlandia.classes import CLASSES
from flatlandia.plumbing import escape
from flatlandia.plumbing.files import atomic_path, write_text
from flatlandia.report import figures


def reference_table(
    scene: str,
    lonlat: np.ndarray,
    classes: np.ndarray,
    labels: list[str],
    frame: geo.MetricFrame | None,
    xy: np.ndarray | None = None,
) -> pd.DataFrame:
    """One row per object: its index in the published map, class, lon/lat and x/y (metres of
    ``frame``; a local-frame map without GPS has no frame: its ``xy`` are given, lon/lat NaN)."""
    xy = frame.to_xy(lonlat) if xy is None else np.asarray(xy, float).reshape(-1, 2)
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
        "frame": "gps",
        "crs": frame.proj4,
        "lon0": frame.lon0,
        "lat0": frame.lat0,
        "unit": "m",
        "axes": "x east, y north, metres (transverse Mercator centred on the scene)",
    }


def local_frame_metadata(scene: str, unit: str) -> dict:
    """A map without GPS (images.align.mode: none): no CRS, x/y on the SfM ground plane."""
    return {
        "scene": scene,
        "frame": "local",
        "crs": None,
        "lon0": None,
        "lat0": None,
        "unit": unit,
        "axes": (
            f"x, y on the SfM ground plane (normal to the cameras' mean up axis), origin at the cameras' "
            f"centroid, unit: {unit}; no geographic position (no lon/lat)"
        ),
    }


def is_local(meta: dict) -> bool:
    return meta.get("frame") == "local"


def published_reference_map(scene: str, lonlat: np.ndarray, classes: np.ndarray) -> tuple[pd.DataFrame, dict]:
    """Rule reference_map on a published scene -> (table, metadata): the published map
    (lon/lat, class ids) in the scene's metric frame (:func:`flatlandia.geo.frame_for`)."""
    frame = geo.frame_for(lonlat)
    return reference_table(scene, lonlat, classes, CLASSES, frame), frame_metadata(scene, frame)


def images_reference_map(scene: str, objects: pd.DataFrame, objects_meta: dict) -> tuple[pd.DataFrame, dict]:
    """Rule reference_map on an images scene -> (table, metadata): its objects (rule objects'
    table and metadata) that carry a 42-class label, in the frame of its GPS alignment (a local
    frame without GPS: x/y on the SfM ground plane, no lon/lat); ``object_id`` links them back."""
    objs = objects[objects["class_id"].astype(int) < len(CLASSES)].reset_index(drop=True)
    lonlat = objs[["lon", "lat"]].to_numpy(float).reshape(-1, 2)
    xy = objs[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2)
    if objects_meta.get("frame") == "local":  # photos without GPS: the SfM ground plane, no lon/lat
        frame, frame_meta = None, local_frame_metadata(scene, objects_meta["unit"])
    else:
        frame = geo.MetricFrame(lon0=objects_meta["lon0"], lat0=objects_meta["lat0"])
        frame_meta = frame_metadata(scene, frame)
    ref = reference_table(scene, lonlat, objs["class_id"].to_numpy(np.int64), CLASSES, frame, xy)
    ref["object_id"] = objs["object_id"].to_numpy(np.int64)
    return ref, {**frame_meta, "source": "images: objects from the classified SfM model"}


def geojson(ref: pd.DataFrame, meta: dict) -> dict:
    """A FeatureCollection of the objects as points in EPSG:4326 (RFC 7946 order lon, lat); a
    local-frame map (no GPS) has its x/y as coordinates, in no geographic CRS (see its metadata)."""
    local = is_local(meta)
    feats = [
        {
            "type": "Feature",
            "geometry": {
                "type": "Point",
                "coordinates": [float(r.x_m), float(r.y_m)] if local else [float(r.lon), float(r.lat)],
            },
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
    """GeoParquet (EPSG:4326 points; a local-frame map: x/y points without CRS) with the frame
    metadata; opens in QGIS and geopandas."""
    import geopandas as gpd

    if is_local(meta):
        gdf = gpd.GeoDataFrame(ref.copy(), geometry=gpd.points_from_xy(ref["x_m"], ref["y_m"]), crs=None)
    else:
        gdf = gpd.GeoDataFrame(ref.copy(), geometry=gpd.points_from_xy(ref["lon"], ref["lat"]), crs="EPSG:4326")
    with atomic_path(path) as tmp:
        gdf.to_parquet(tmp, index=False)
        # keep the metric frame next to the geo metadata
        import pyarrow.parquet as pq

        table = pq.read_table(tmp)
        md = dict(table.schema.metadata or {})
        md[b"flatlandia"] = json.dumps(meta, sort_keys=True).encode()
        pq.write_table(table.replace_schema_metadata(md), tmp)


def axis_labels(meta: dict) -> tuple[str, str]:
    """Axis names of a map: east/north metres, or a local frame's x/y in its unit."""
    if is_local(meta):
        return f"x ({meta.get('unit', 'SfM unit')})", f"y ({meta.get('unit', 'SfM unit')})"
    return "x east (m)", "y north (m)"


def plot_reference_map(
    ref: pd.DataFrame,
    queries: pd.DataFrame | None,
    path: str | Path,
    title: str,
    axes: tuple[str, str] = ("x east (m)", "y north (m)"),
    empty_because: str = "",
) -> None:
    """Objects coloured by class, query cameras with heading arrows, in the map's unit. A map
    without objects says so in words (and ``empty_because``), not as blank axes."""
    plt = figures.pyplot()

    if not len(ref):
        _plot_empty_map(plt, path, title, empty_because)
        return
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    cmap = plt.get_cmap("tab20")
    for k, (label, grp) in enumerate(ref.groupby("class_label", sort=True)):
        ax.scatter(
            grp["x_m"],
            grp["y_m"],
            s=22,
            color=cmap(k % 20),
            label=escape.mathtext(f"{label} ({len(grp)})"),
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
    ax.set_xlabel(escape.mathtext(axes[0]))  # text from files: '$' would start mathtext
    ax.set_ylabel(escape.mathtext(axes[1]))
    ax.set_title(escape.mathtext(title))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)


def _plot_empty_map(plt, path: str | Path, title: str, empty_because: str) -> None:
    """The figure of a map without objects: its title and "no objects", with why when known (the
    default segmentation of an images scene labels no object class), in place of empty axes."""
    import textwrap

    fig, ax = plt.subplots(figsize=(8, 3), dpi=110)
    ax.axis("off")
    ax.set_title(escape.mathtext(title))
    ax.text(0.5, 0.62, "no objects", ha="center", va="center", fontsize=16, transform=ax.transAxes)
    if empty_because:
        why = textwrap.fill(escape.mathtext(empty_because), 70)
        ax.text(0.5, 0.3, why, ha="center", va="center", fontsize=9, color="0.3", transform=ax.transAxes)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
