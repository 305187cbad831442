"""Rule export_scene: a benchmark scene's inputs as plain files under results/export/{scene}/.

The reference map (CSV, GeoJSON) and its frame, the queries and their GT and depth local maps,
the proposals (the oracle GT-BB box of every query; the coarse stages' tables that exist, test
split) and, in files of their own, the ground truth (CSV, and the query cameras as GeoJSON points;
flatlandia.data.export.scene_export).
"""

import json

import pandas as pd

from flatlandia.data import export
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scene = smk.wildcards.scene
    sources = list(smk.params.sources)
    coarse = {s: pd.read_parquet(p) for s, p in zip(sources, smk.input.proposals, strict=True)}
    out = export.scene_export(
        scene,
        pd.read_parquet(smk.input.reference_map),
        files.read_parquet_metadata(smk.input.reference_map),
        pd.read_parquet(smk.input.queries),
        coarse,
    )
    for name in ("reference_map", "queries", "local_maps", "proposals", "ground_truth"):
        files.write_text(export.csv_text(out[name]), smk.output[name])
    files.write_text(json.dumps(out["reference_geojson"], indent=1) + "\n", smk.output.reference_geojson)
    files.write_text(json.dumps(out["query_cameras"], indent=1) + "\n", smk.output.query_cameras)
    files.write_json(out["frame"], smk.output.frame)
    absent = [s for s in export.COARSE_SOURCES if s not in coarse]
    log.info(
        "scene %s: %d objects, %d queries (%s), %d local-map rows; proposals %s; absent sources: %s",
        scene,
        len(out["reference_map"]),
        len(out["queries"]),
        out["queries"]["split"].value_counts().to_dict(),
        len(out["local_maps"]),
        out["proposals"].groupby("source", sort=False)["token"].nunique().to_dict(),
        ", ".join(absent) or "none",
    )


rule_log.run(main, snakemake)  # noqa: F821
