"""Rule images_objects: classified SfM points + GPS alignment -> objects (boxes) and their map positions."""

import json

import numpy as np
import pandas as pd

from flatlandia import io, runlog
from flatlandia.classes import CLASSES
from flatlandia.images import gps_alignment
from flatlandia.objects import clustering


def main(smk, log):
    scene = smk.wildcards.scene
    points = pd.read_parquet(smk.input.points)
    alignment = json.loads(open(smk.input.alignment).read())
    params = clustering.ClusterParams(**dict(smk.params.cluster))
    instances = pd.read_parquet(smk.input.instances)
    objs, member = gps_alignment.scene_objects(
        scene, points, alignment, params, CLASSES, source=str(smk.input.points), instances=instances
    )
    meta = {
        "scene": scene,
        "crs": alignment["crs"],
        "lon0": alignment["frame_lon0"],
        "lat0": alignment["frame_lat0"],
        "metres_per_sfm_unit": alignment["metres_per_sfm_unit"],
        "cluster_params": dict(smk.params.cluster),
        "coordinates": "cx/cy/cz, box_* in SfM units; x_m/y_m metric frame of the GPS alignment; lon/lat WGS84",
        "label": "majority 42-class of the object's points",
        "instance_split": bool(len(instances)),
    }  # clusters split by the image instances their points fall on
    if objs.empty:
        meta["empty_because"] = (
            "no SfM point carries an object class (e.g. the offline segmentation backend "
            "labels none): no objects, hence an empty reference map and no queries"
        )
        log.warning("scene %s: %s", scene, meta["empty_because"])
    io.write_parquet(objs, smk.output.parquet, meta)
    io.write_parquet(
        pd.DataFrame({"point3D_id": points["point3D_id"].to_numpy(np.int64), "object_id": member}),
        smk.output.members,
        {"scene": scene},
    )
    clustering.write_boxes_ply(objs, smk.output.ply)
    log.info(
        "scene %s: %d object points, %d objects %s",
        scene,
        int((member >= 0).sum()),
        len(objs),
        objs["class_label"].value_counts().to_dict() if len(objs) else {},
    )


runlog.run(main, snakemake)  # noqa: F821
