"""Rule classify_points: majority class of each 3D point's observations; classified PLY; the
instances its observations fall on (when instance images are configured)."""

from pathlib import Path

import pycolmap

from flatlandia.images import classify_points
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    rec = pycolmap.Reconstruction(smk.input.model)
    names = [img.name for img in rec.images.values()]
    maps = classify_points.load_class_maps(Path(smk.input.classes), names)
    pts = classify_points.point_votes(rec, maps)
    inst = classify_points.point_instances(
        rec, classify_points.load_instance_maps(smk.params["segment.instances_dir"], names)
    )
    files.write_parquet(pts, smk.output.points)
    files.write_parquet(inst, smk.output.instances, {"instances_dir": str(smk.params["segment.instances_dir"])})
    classify_points.write_classified_ply(pts, Path(smk.output.ply))
    n_obj = int((pts["class_id"] != 255).sum())
    log.info(
        "%d observations on %d instances (segment.instances_dir %s)",
        len(inst),
        inst["key"].nunique(),
        smk.params["segment.instances_dir"],
    )
    log.info(
        "%d points, %d on objects (%s)",
        len(pts),
        n_obj,
        pts.loc[pts["class_id"] != 255, "class_id"].value_counts().to_dict(),
    )


rule_log.run(main, snakemake)  # noqa: F821
