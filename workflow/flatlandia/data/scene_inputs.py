"""A published-format scene's benchmark inputs in one call: the recipe of rules reference_map ->
recover -> queries, run in process on their entry functions with the config's settings.

Why: tests, notebooks and benchmarks need a scene's reference map and queries without running
Snakemake; each rebuilt the chain by hand (and could drift from the rules). Here it is once, in
hloc's manner (a short recipe chaining the stages' own functions)::

    from flatlandia.data import scene_inputs

    scene = scene_inputs.published_scene("tests/data/tiny", "0")  # or ../shared/flatlandia, "9"
    scene.ref, scene.queries                                       # the two tables the rules write
    scene.write("results")                                          # ... at the workflow's paths

Settings (``recover.tol_m``, ``seed``, ``split``) come from a config (a resolved one, as
Snakemake's; None: the schema's defaults). Images scenes need SfM (rules sfm ... queries): not here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import config, geo
from flatlandia.classes import CLASSES
from flatlandia.data import published, queries, recover, reference_map
from flatlandia.plumbing import files


@dataclass
class SceneInputs:
    """One scene's inputs as the rules make them: the published map (``lonlat``, ``classes``) and
    local maps (``local_maps``: token -> {"GT", "depth"}), rule reference_map's table and metadata
    (``ref``, ``meta``), rule recover's table (``recovered``) and rule queries' (``queries``)."""

    scene: str
    lonlat: np.ndarray
    classes: np.ndarray
    local_maps: dict[str, dict[str, np.ndarray]]
    ref: pd.DataFrame
    meta: dict
    recovered: pd.DataFrame
    queries: pd.DataFrame
    queries_meta: dict

    @property
    def frame(self) -> geo.MetricFrame:
        """The scene's metric frame (the reference map's)."""
        return geo.MetricFrame(self.meta["lon0"], self.meta["lat0"])

    def split(self, name: str) -> pd.DataFrame:
        """The queries of one split (train, val, test)."""
        return self.queries[self.queries["split"] == name].reset_index(drop=True)

    def write(self, results: str | Path, geojson: bool = False) -> Path:
        """Write ``results``/{scene}/maps/reference_map.parquet (and .geojson when asked) and
        ``results``/{scene}/queries/queries.parquet as rules reference_map and queries write them;
        returns the reference map's path."""
        folder = Path(results) / self.scene
        path = folder / "maps" / "reference_map.parquet"
        reference_map.write_geoparquet(self.ref, self.meta, path)
        if geojson:
            reference_map.write_geojson(self.ref, self.meta, path.with_suffix(".geojson"))
        files.write_parquet(self.queries, folder / "queries" / "queries.parquet", self.queries_meta)
        return path


def published_scene(root: str | Path, scene: str, cfg: dict | None = None) -> SceneInputs:
    """Scene ``scene`` of a folder in the published format (``root``: individual_reference_maps/,
    local_maps.json), through rules reference_map, recover and queries with the settings of ``cfg``
    (None: the schema's defaults)."""
    cfg = config.resolve(cfg)
    root, scene = Path(root), str(scene)
    lonlat, classes = published.read_reference_map(root / f"individual_reference_maps/map_{scene}.json", len(CLASSES))
    ref, meta = reference_map.published_reference_map(scene, lonlat, classes)
    local = published.read_local_maps(root / "local_maps.json", scene)
    rec = recover.recover_scene(scene, lonlat, classes, local, tol_m=cfg["recover"]["tol_m"])
    q, q_meta = queries.published_scene_queries(scene, rec, ref, meta, local, cfg["seed"], cfg["split"])
    return SceneInputs(scene, lonlat, classes, local, ref, meta, rec, q, q_meta)
