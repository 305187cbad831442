"""Rule objects: classified point cloud -> objects (clusters per macro-class, boxes) + object map."""

from flatlandia import geo, io, runlog
from flatlandia.classes import CLASSES
from flatlandia.objects import clustering


def main(smk, log):
    scene = smk.wildcards.scene
    pts, labels = clustering.read_classified_cloud(smk.input.cloud)
    t = io.read_transformations(smk.input.transformations)
    params = clustering.ClusterParams(**dict(smk.params.cluster))
    mpu = clustering.metres_per_unit(t)
    objs = clustering.cluster_objects(pts, labels, mpu, params, source=str(smk.input.cloud))
    # label transfer from the other scenes' class labels only (no positions, not this scene)
    others = [io.read_reference_map(p, n_classes=len(CLASSES))[1] for p in smk.input.other_maps]
    prior = clustering.class_prior(others)
    # the scene's metric frame (origin only) is the one every other stage uses
    frame = geo.frame_for(io.read_reference_map(smk.input.reference_map)[0])
    ref = clustering.objects_reference_map(objs, t, frame, prior)
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
    clustering.write_boxes_ply(objs, smk.output.ply)
    log.info(
        "scene %s: %d classified of %d points, %d objects (%s), %.4f m per SfM unit",
        scene,
        int((labels != clustering.BACKGROUND).sum()),
        len(pts),
        len(objs),
        objs["macro_class"].value_counts().to_dict(),
        mpu,
    )


runlog.run(main, snakemake)  # noqa: F821
