"""A map table's rows at the door: a GeoParquet or Parquet (its ``flatlandia`` metadata: the
workflow's frame) or a GeoJSON of classed points (:func:`read_table`), its classes
(:func:`table_classes`) and numbers (:func:`numbers`), each problem one InputError naming the file.

Why a module of its own: what a table file holds is one job, how a scene map is built from it
(:mod:`flatlandia.localize.scene_map`) another; a kind of map read from a table reads it here.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from flatlandia.localize.query_files import class_ids
from flatlandia.plumbing import validate
from flatlandia.plumbing.errors import InputError

if TYPE_CHECKING:
    import pandas as pd

#: class properties of a map, in the order they are looked for (labels before ids)
LABEL_KEYS = ("class_label", "class", "label")


ID_KEY = "class_id"


#: lon/lat column names of a map table
LON_KEYS, LAT_KEYS = ("lon", "longitude", "lng"), ("lat", "latitude")


def pick(columns, keys) -> str | None:
    """The first of ``keys`` among a table's columns, matched without case (None: none)."""
    low = {str(c).lower(): c for c in columns}
    return next((low[k] for k in keys if k in low), None)


def table_classes(df: pd.DataFrame, path: Path) -> np.ndarray:
    """(N,) class ids of a map table: its labels (:data:`LABEL_KEYS`) or else its ids (:data:`ID_KEY`)."""
    key = pick(df.columns, LABEL_KEYS)
    if key is not None:
        return class_ids(df[key].tolist(), path, "object", ids=False)
    if ID_KEY in df.columns:
        return class_ids(df[ID_KEY].tolist(), path, "object", ids=True)
    raise InputError(path, f"no class property: expected one of {', '.join(LABEL_KEYS + (ID_KEY,))}")


def read_table(path: Path) -> tuple[pd.DataFrame, dict]:
    """A map table from Parquet (its ``flatlandia`` metadata: the workflow's frame) or GeoJSON."""
    import pandas as pd

    from flatlandia.plumbing import files

    if path.suffix.lower() == ".parquet":
        try:
            df = validate.read_parquet(  # bounded on what it decodes to, not only on disk
                path, validate.MAX_MAP_OBJECTS, validate.MAX_MAP_BYTES, "objects", ("MAX_MAP_OBJECTS", "MAX_MAP_BYTES")
            ).to_pandas()
            meta = files.read_parquet_metadata(path)
        except InputError:
            raise
        except Exception as e:  # pyarrow raises several types for files that are not Parquet
            raise InputError(
                path, f"not a readable Parquet file ({type(e).__name__}: {validate.one_line(e)})"
            ) from None
        if "geometry" in df.columns and not (pick(df.columns, LON_KEYS) and pick(df.columns, LAT_KEYS)):
            df = geometry_lonlat(path, df)
        return df, meta
    doc = validate.read_json(path, validate.MAX_MAP_BYTES, "MAX_MAP_BYTES")
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list):
        raise InputError(path, "not GeoJSON: expected a FeatureCollection with a list of features")
    validate.count(len(feats), validate.MAX_MAP_OBJECTS, path, "features", "MAX_MAP_OBJECTS")
    meta = doc.get("flatlandia") if isinstance(doc.get("flatlandia"), dict) else {}
    rows = []
    for k, f in enumerate(feats):
        geom = f.get("geometry") if isinstance(f, dict) else None
        coords = geom.get("coordinates") if isinstance(geom, dict) else None
        if not isinstance(geom, dict) or geom.get("type") != "Point" or not isinstance(coords, list) or len(coords) < 2:
            raise InputError(path, f"feature {k}: expected a Point geometry with [lon, lat] coordinates")
        if any(isinstance(c, bool) for c in coords[:2]):
            raise InputError(path, f"feature {k}: coordinates must be numbers, not true/false")
        props = f.get("properties")
        if props is not None and not isinstance(props, dict):
            raise InputError(
                path, f"feature {k}: properties must be a JSON object (or null), not {type(props).__name__}"
            )
        rows.append({**(props or {}), "lon": coords[0], "lat": coords[1]})
    df = pd.DataFrame(rows)
    if meta.get("frame") == "local":  # a map without GPS: its coordinates are x/y, not lon/lat
        df = df.drop(columns=["lon", "lat"])
    return df, meta


def geometry_lonlat(path: Path, df: pd.DataFrame) -> pd.DataFrame:
    """lon/lat columns of a GeoParquet without them, from its point geometries (in EPSG:4326)."""
    try:
        import geopandas as gpd

        g = gpd.read_parquet(path)
        if g.crs is not None and not g.crs.equals("EPSG:4326") and not g.crs.equals("OGC:CRS84"):
            g = g.to_crs("EPSG:4326")
        if not (g.geometry.geom_type == "Point").all():
            raise InputError(path, "the geometries must be points (one per object)")
        return df.assign(lon=g.geometry.x.to_numpy(), lat=g.geometry.y.to_numpy())
    except InputError:
        raise
    except Exception as e:
        raise InputError(
            path, f"could not read its point geometries ({type(e).__name__}: {validate.one_line(e)})"
        ) from None


def numbers(df: pd.DataFrame, columns: list[str], path: Path, dtype=float) -> np.ndarray:
    """(N, len(columns)) numbers of a map's columns; InputError naming the column otherwise."""
    out = np.empty((len(df), len(columns)), dtype)
    for j, c in enumerate(columns):
        try:
            v = df[c].to_numpy(float)
        except (TypeError, ValueError) as e:
            raise InputError(path, f"{c}: not numbers ({e})") from None
        if dtype is not float and not (np.isfinite(v).all() and (v == np.round(v)).all()):
            raise InputError(path, f"{c}: not integers")
        out[:, j] = v
    return out
