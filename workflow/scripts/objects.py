"""Rule objects: a scene's classified points -> objects (clusters per macro-class, boxes) + their map positions.

The scene's source (config/scenes.tsv) decides the input: a published scene starts from its
class point cloud and takes positions through the published chain and 42-class labels by label
transfer (:mod:`flatlandia.objects.labels`); an images scene starts from its classified SfM
points and takes positions through its GPS alignment.
"""

import numpy as np
import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia.classes import CLASSES
from flatlandia.images import gps_alignment
from flatlandia.objects import cloud, clustering, labels


def published_scene(smk, log):
    scene = smk.wildcards.scene
    pts, point_labels = cloud.read_classified_cloud(smk.input.cloud)
    t = io.read_transformations(smk.input.transformations)
    params = clustering.ClusterParams.from_dict(smk.params.cluster)
    mpu = cloud.metres_per_unit(t)
    objs, member = clustering.cluster_objects(
        pts, point_labels, mpu, params, source=str(smk.input.cloud), with_members=True
    )
    # label transfer from the other scenes' class labels only (no positions, not this scene)
    others = [io.read_reference_map(p, n_classes=len(CLASSES))[1] for p in smk.input.other_maps]
    prior = labels.class_prior(others)
    # the scene's metric frame (origin only) is the one every other stage uses
    frame = geo.frame_for(io.read_reference_map(smk.input.reference_map)[0])
    ref = labels.objects_reference_map(objs, t, frame, prior)
    table = objs.merge(ref.drop(columns=["macro_class", "n_points"]), on="object_id")
    table.insert(0, "scene", scene)
    meta = {
        "scene": scene,
        "crs": frame.proj4,
        "lon0": frame.lon0,
        "lat0": frame.lat0,
        "metres_per_sfm_unit": mpu,
        "cluster_params": dict(smk.params.cluster),
        "coordinates": "cx/cy/cz, box_* in SfM units; lon/lat via the published chain; x_m/y_m metric frame",
        "label_transfer": "per macro-class the most frequent 42-class among the other scenes' published maps",
        "class_prior": prior,
    }
    io.write_parquet(table, smk.output.parquet, meta)
    in_object = np.flatnonzero(member >= 0)
    io.write_parquet(
        pd.DataFrame({"point_index": in_object.astype(np.int64), "object_id": member[in_object]}),
        smk.output.members,
        {"scene": scene, "point_index": "vertex row of the class cloud; points in no object are left out"},
    )
    clustering.write_boxes_ply(objs, smk.output.ply)
    log.info(
        "scene %s: %d classified of %d points, %d objects (%s), %.4f m per SfM unit",
        scene,
        int((point_labels != cloud.BACKGROUND).sum()),
        len(pts),
        len(objs),
        objs["macro_class"].value_counts().to_dict(),
        mpu,
    )


def images_scene(smk, log):
    scene = smk.wildcards.scene
    points = pd.read_parquet(smk.input.points)
    alignment = io.read_json(smk.input.alignment)
    params = clustering.ClusterParams.from_dict(smk.params.cluster)
    instances = pd.read_parquet(smk.input.instances)
    objs, member = labels.images_scene_objects(
        scene, points, alignment, params, CLASSES, source=str(smk.input.points), instances=instances
    )
    local = gps_alignment.is_local(alignment)
    meta = {
        "scene": scene,
        "frame": "local" if local else "gps",
        "crs": alignment["crs"],
        "lon0": alignment["frame_lon0"],
        "lat0": alignment["frame_lat0"],
        "unit": alignment.get("unit", "m"),
        "metres_per_sfm_unit": alignment["metres_per_sfm_unit"],
        "cluster_params": dict(smk.params.cluster),
        "coordinates": (
            "cx/cy/cz, box_* in SfM units; x_m/y_m on the SfM ground plane in the local frame's unit; no lon/lat"
            if local
            else "cx/cy/cz, box_* in SfM units; x_m/y_m metric frame of the GPS alignment; lon/lat WGS84"
        ),
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


def main(smk, log):
    if smk.params.source == "images":
        images_scene(smk, log)
    else:
        published_scene(smk, log)


runlog.run(main, snakemake)  # noqa: F821
