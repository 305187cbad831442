"""Rule objects: a scene's classified points -> objects (clusters per macro-class, boxes) + their map positions.

The scene's source (config/scenes.tsv) decides the input: a published scene starts from its
class point cloud and takes positions through the published chain and 42-class labels by label
transfer (:mod:`flatlandia.objects.labels`); an images scene starts from its classified SfM
points and takes positions through its GPS alignment. The logic: :mod:`flatlandia.objects.scene_objects`.
"""

import pandas as pd

from flatlandia.classes import CLASSES
from flatlandia.data import published
from flatlandia.objects import cloud, clustering, scene_objects
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    name, cluster = smk.wildcards.scene, dict(smk.params["objects.cluster"])
    if smk.params.source == "images":
        out = scene_objects.images_objects(
            name,
            pd.read_parquet(smk.input.points),
            files.read_json(smk.input.alignment),
            pd.read_parquet(smk.input.instances),
            cluster,
            source=str(smk.input.points),
        )
    else:
        pts, point_labels = cloud.read_classified_cloud(smk.input.cloud)
        out = scene_objects.published_objects(
            name,
            pts,
            point_labels,
            published.read_transformations(smk.input.transformations),
            published.read_reference_map(smk.input.reference_map)[0],
            [published.read_reference_map(p, n_classes=len(CLASSES))[1] for p in smk.input.other_maps],
            cluster,
            source=str(smk.input.cloud),
        )
    if "empty_because" in out.meta:
        log.warning("scene %s: %s", name, out.meta["empty_because"])
    files.write_parquet(out.objects, smk.output.parquet, out.meta)
    files.write_parquet(out.members, smk.output.members, out.members_meta)
    clustering.write_boxes_ply(out.objects, smk.output.ply)
    log.info("%s", out.summary)


rule_log.run(main, snakemake)  # noqa: F821
