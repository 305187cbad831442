"""Rule reference_map: a scene's reference map as GeoParquet + GeoJSON in its metric frame.

A published scene's map is the published one; an images scene's map is its objects (those
with a 42-class label), in the metric frame of its GPS alignment
(flatlandia.data.reference_map: ``published_reference_map``, ``images_reference_map``).
"""

from pathlib import Path

import pandas as pd

from flatlandia.classes import CLASSES
from flatlandia.data import published, reference_map
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scene = smk.wildcards.scene
    if smk.params.source == "images":
        ref, meta = reference_map.images_reference_map(
            scene, pd.read_parquet(smk.input.objects), files.read_parquet_metadata(smk.input.objects)
        )
    else:
        lonlat, classes = published.read_reference_map(
            Path(smk.params.root) / f"individual_reference_maps/map_{scene}.json", n_classes=len(CLASSES)
        )
        ref, meta = reference_map.published_reference_map(scene, lonlat, classes)
    reference_map.write_geoparquet(ref, meta, smk.output.parquet)
    reference_map.write_geojson(ref, meta, smk.output.geojson)
    log.info(
        "scene %s: %d objects, %d classes on the reference map, frame %s",
        scene,
        len(ref),
        ref["class_id"].nunique(),
        meta["crs"] or f"local ({meta['unit']})",
    )


rule_log.run(main, snakemake)  # noqa: F821
