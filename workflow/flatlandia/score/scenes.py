"""The benchmark's scenes as scoring reads them from a results folder: each scene's reference map,
queries (every split) and metric frame (:func:`read_scene`, :func:`results_scenes`).

Why through the doors: a results folder given to ``flatlandia score --results`` is a user's, as a
map given to ``flatlandia localize`` is, so its files pass the same checks
(:mod:`flatlandia.plumbing.validate`): regular Parquet files within their bounds, a map's frame
degrees near its own objects and its metres its lon/lat in that frame (``frame_origin``,
``frame_matches``, as ``localize.load_map``), every truth finite (``ground_truth``, as the training
cameras ``localize`` reads); each problem one :class:`InputError` naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, paths
from flatlandia.classes import CLASSES
from flatlandia.plumbing import files, validate
from flatlandia.plumbing.errors import InputError
from flatlandia.plumbing.names import plain_name

#: the reference map's columns scoring reads (rule reference_map's table)
MAP_COLUMNS = ("obj_idx", "class_id", "lon", "lat", "x_m", "y_m")
#: the queries' columns scoring reads (rule queries' table)
QUERY_COLUMNS = ("scene", "token", "split", "x_m", "y_m", "theta_deg", "ref_idx", "n_objects", "classes")


@dataclass(frozen=True)
class BenchmarkScene:
    """One benchmark scene as scoring needs it: its reference map, its queries (every split) and
    its metric frame (None for a map without GPS)."""

    scene: str
    ref: pd.DataFrame
    queries: pd.DataFrame
    frame: geo.MetricFrame | None


def read_table(path: str | Path, max_rows: int, max_bytes: int, names: tuple[str, str], columns=None) -> pd.DataFrame:
    """A Parquet table of a results folder, through the Parquet door
    (:func:`flatlandia.plumbing.validate.read_table`)."""
    return validate.read_table(path, max_rows, max_bytes, names, columns)


def _map_frame(ref: pd.DataFrame, meta: dict, path: str | Path) -> geo.MetricFrame | None:
    """The map's metric frame, checked as ``localize`` checks a map (None: a map without GPS)."""
    validate.columns(ref, MAP_COLUMNS, path)
    for c in ("obj_idx", "class_id"):
        if ref[c].dtype.kind not in "iu":
            raise InputError(path, f"{c}: not integers ({ref[c].dtype})")
    validate.unique_ids(ref["obj_idx"].to_numpy(), path)
    cls = ref["class_id"].to_numpy()
    if len(cls) and (cls.min() < 0 or cls.max() >= len(CLASSES)):
        raise InputError(path, f"class_id outside 0..{len(CLASSES) - 1}")
    xy = validate.finite_array(ref[["x_m", "y_m"]].to_numpy(float), path, "x_m/y_m")
    origin = validate.frame_origin(meta, path)
    if origin is None or meta.get("frame") == "local":
        return None
    lonlat = validate.lonlat_degrees(ref[["lon", "lat"]].to_numpy(float), path)
    frame = geo.MetricFrame(*origin)
    validate.frame_matches(lonlat, xy, frame.to_xy, origin, path)  # a forged lon0 is the map's error
    return frame


def read_scene(reference_map: str | Path, queries: str | Path) -> BenchmarkScene:
    """A scene from the workflow's files: results/{scene}/maps/reference_map.parquet (its frame in
    the Parquet metadata ``flatlandia``) and results/{scene}/queries/queries.parquet, each through
    its door (module docstring)."""
    for p in (reference_map, queries):
        if not os.path.lexists(p):
            raise InputError(p, "missing: run the workflow first (`snakemake --cores 2 benchmark`)")
    ref = read_table(
        reference_map, validate.MAX_MAP_OBJECTS, validate.MAX_MAP_BYTES, ("MAX_MAP_OBJECTS", "MAX_MAP_BYTES")
    )
    meta = files.read_parquet_metadata(reference_map)
    frame = _map_frame(ref, meta, reference_map)
    q = read_table(
        queries, validate.MAX_QUERIES, validate.MAX_QUERY_TABLE_BYTES, ("MAX_QUERIES", "MAX_QUERY_TABLE_BYTES")
    )
    validate.columns(q, QUERY_COLUMNS, queries)
    tokens = q["token"].astype(str).to_numpy()
    validate.ground_truth(
        q, queries, lambda i: f"row {i + 1} (token {validate.shown(tokens[i])})", np.asarray(ref["obj_idx"])
    )
    scene = str(meta.get("scene", ref["scene"].iloc[0] if len(ref) and "scene" in ref.columns else ""))
    return BenchmarkScene(scene, ref, q, frame)


#: the record of the scenes the benchmark in a results folder was built on, in that folder
#: (paths.BENCHMARK_RECORD; common.smk reads it too)
BENCHMARK_RECORD = str(paths.within("", paths.BENCHMARK_RECORD))


def results_scenes(results: str | Path) -> dict[str, BenchmarkScene]:
    """The benchmark scenes of a results folder (those of its ``tables/dataset_stats_per_scene.parquet``)."""
    results = Path(results)
    record = results / BENCHMARK_RECORD
    if not os.path.lexists(record):
        raise InputError(
            record,
            "missing: the benchmark's scenes are read from it (build the benchmark first: `snakemake --cores 2 benchmark`)",
        )
    table = read_table(record, validate.MAX_SCENES, validate.MAX_MAP_BYTES, ("MAX_SCENES", "MAX_MAP_BYTES"))
    validate.columns(table, ("scene",), record)
    ids = [plain_name(str(s), record, "scene id") for s in table["scene"]]  # ids become paths
    twice = sorted({s for s in ids if ids.count(s) > 1}) if len(set(ids)) < len(ids) else []
    if twice:  # a record naming one scene 1,000 times read it 1,000 times (the fuzz suite's find)
        raise InputError(record, f"scene {validate.shown(twice[0])} is listed more than once: each scene once")
    return {
        s: read_scene(paths.within(results, paths.reference_map(s)), paths.within(results, paths.queries(s)))
        for s in ids
    }
