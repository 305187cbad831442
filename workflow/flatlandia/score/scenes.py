"""The benchmark's scenes as scoring reads them from a results folder: each scene's reference map,
queries (every split) and metric frame (:func:`read_scene`, :func:`results_scenes`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from flatlandia import geo, paths
from flatlandia.plumbing import files
from flatlandia.plumbing.errors import InputError


@dataclass(frozen=True)
class BenchmarkScene:
    """One benchmark scene as scoring needs it: its reference map, its queries (every split) and
    its metric frame (None for a map without GPS)."""

    scene: str
    ref: pd.DataFrame
    queries: pd.DataFrame
    frame: geo.MetricFrame | None


def read_scene(reference_map: str | Path, queries: str | Path) -> BenchmarkScene:
    """A scene from the workflow's files: results/{scene}/maps/reference_map.parquet (its frame in
    the Parquet metadata ``flatlandia``) and results/{scene}/queries/queries.parquet."""
    for p in (reference_map, queries):
        if not Path(p).exists():
            raise InputError(p, "missing: run the workflow first (`snakemake --cores 2 benchmark`)")
    meta = files.read_parquet_metadata(reference_map)
    ref, q = pd.read_parquet(reference_map), pd.read_parquet(queries)
    scene = str(meta.get("scene", ref["scene"].iloc[0] if len(ref) else ""))
    frame = geo.MetricFrame(float(meta["lon0"]), float(meta["lat0"])) if meta.get("lon0") is not None else None
    return BenchmarkScene(scene, ref, q, frame)


#: the record of the scenes the benchmark in a results folder was built on, in that folder
#: (paths.BENCHMARK_RECORD; common.smk reads it too)
BENCHMARK_RECORD = str(paths.within("", paths.BENCHMARK_RECORD))


def results_scenes(results: str | Path) -> dict[str, BenchmarkScene]:
    """The benchmark scenes of a results folder (those of its ``tables/dataset_stats_per_scene.parquet``)."""
    results = Path(results)
    record = results / BENCHMARK_RECORD
    if not record.exists():
        raise InputError(
            record,
            "missing: the benchmark's scenes are read from it (build the benchmark first: `snakemake --cores 2 benchmark`)",
        )
    ids = [str(s) for s in pd.read_parquet(record, columns=["scene"])["scene"]]
    return {
        s: read_scene(paths.within(results, paths.reference_map(s)), paths.within(results, paths.queries(s)))
        for s in ids
    }
