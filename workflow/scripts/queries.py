"""Rule queries: a scene's query table, one row per query (3DoF pose, GT and depth local maps, split).

A published scene's queries are its published local maps, with the ground truth recovered by
registration (rule recover: flatlandia.data.queries.published_scene_queries); an images scene's
are its images that see at least ``images.min_objects`` objects, posed by the GPS-aligned SfM
model (flatlandia.images.image_queries.images_scene_queries).
"""

from pathlib import Path

import pandas as pd

from flatlandia.data import published, queries
from flatlandia.images import image_queries
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scene = smk.wildcards.scene
    ref = pd.read_parquet(smk.input.reference_map)
    if smk.params.source == "images":
        import pycolmap

        p = smk.params
        images = {
            "min_objects": p["images.min_objects"],
            "min_points": p["images.min_points"],
            "depth": p["images.depth"],
            "images_dir": smk.input.images,
        }
        q, meta = image_queries.images_scene_queries(
            scene,
            pycolmap.Reconstruction(smk.input.model),
            files.read_json(smk.input.alignment),
            ref,
            pd.read_parquet(smk.input.objects),
            pd.read_parquet(smk.input.members),
            images,
            smk.params["seed"],
            smk.params["split"],
            device=smk.config["device"],
        )
        files.write_parquet(q, smk.output.queries, meta)
        log.info(
            "scene %s: %d of %d registered images see >= %d objects -> %d queries",
            scene,
            len(q),
            meta["views"],
            int(images["min_objects"]),
            len(q),
        )
        return
    q, meta = queries.published_scene_queries(
        scene,
        pd.read_parquet(smk.input.recovered),
        ref,
        files.read_parquet_metadata(smk.input.reference_map),
        published.read_local_maps(Path(smk.params.root) / "local_maps.json", scene),
        smk.params["seed"],
        smk.params["split"],
    )
    files.write_parquet(q, smk.output.queries, meta)
    log.info("scene %s: %d queries, split %s", scene, len(q), q["split"].value_counts().to_dict())


rule_log.run(main, snakemake)  # noqa: F821
