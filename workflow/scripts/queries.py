"""Rule queries: a scene's query table, one row per query (3DoF pose, GT and depth local maps, split).

A published scene's queries are its published local maps, with the ground truth recovered by
registration (rule recover); an images scene's are its images that see at least
``images.min_objects`` objects, posed by the GPS-aligned SfM model.
"""

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia.data import queries
from flatlandia.images import depth, gps_alignment, image_queries
from flatlandia.objects import clustering


def split_fractions(split: dict) -> tuple[float, float, float]:
    return tuple(split[k] for k in ("train", "val", "test"))


def published_scene(smk, log):
    scene = smk.wildcards.scene
    ref = pd.read_parquet(smk.input.reference_map)
    meta = io.read_parquet_metadata(smk.input.reference_map)
    frame = geo.MetricFrame(meta["lon0"], meta["lat0"])
    rec = pd.read_parquet(smk.input.recovered)
    local = io.read_local_maps(Path(smk.params.root) / "local_maps.json", scene)
    split = queries.split_queries(list(rec["token"]), smk.params.seed, split_fractions(smk.params.split), salt=scene)
    q = queries.build_queries(scene, rec, ref, local, frame, split)
    io.write_parquet(q, smk.output.queries, {**meta, "seed": smk.params.seed, "split": smk.params.split})
    log.info("scene %s: %d queries, split %s", scene, len(q), q["split"].value_counts().to_dict())


def images_scene(smk, log):
    import pycolmap

    scene = smk.wildcards.scene
    images = dict(smk.params.images)
    rec = pycolmap.Reconstruction(smk.input.model)
    views = image_queries.views_from_colmap(rec)
    alignment = io.read_json(smk.input.alignment)
    ref = pd.read_parquet(smk.input.reference_map)
    objs = pd.read_parquet(smk.input.objects)
    objs = objs[objs["object_id"].isin(ref["object_id"])].reset_index(drop=True)
    members = pd.read_parquet(smk.input.members)
    members = members[members["object_id"].isin(objs["object_id"])]
    point_object = dict(zip(members["point3D_id"].astype(int), members["object_id"].astype(int)))
    point_xyz = {int(pid): np.asarray(p.xyz, float) for pid, p in rec.points3D.items()}
    objs["corners"] = [clustering.box_corners(r).tolist() for r in objs.itertuples(index=False)]
    # queries index the reference map by its row (obj_idx), as the published scenes do
    idx_of = dict(zip(ref["object_id"].astype(int), ref["obj_idx"].astype(int)))
    objs["object_id"] = objs["object_id"].map(idx_of)
    point_object = {k: idx_of[v] for k, v in point_object.items()}
    obj_xy = {int(r.obj_idx): np.array([r.x_m, r.y_m]) for r in ref.itertuples(index=False)}
    obj_class = dict(zip(ref["obj_idx"].astype(int), ref["class_id"].astype(int)))
    A, b = np.asarray(alignment["A"], float), np.asarray(alignment["b"], float)
    dcfg = dict(images["depth"])
    lift = depth.make_lifter(
        dcfg["backend"],
        point_xyz,
        images_dir=images["images_dir"],
        weights=dcfg["weights"],
        inverse=bool(dcfg["inverse"]),
    )
    q = image_queries.scene_queries(
        scene,
        views,
        objs,
        point_object,
        point_xyz,
        A,
        b,
        obj_xy,
        obj_class,
        min_objects=int(images["min_objects"]),
        min_points=int(images["min_points"]),
        lift=lift,
    )
    frame = gps_alignment.frame_of(alignment)  # None: a local frame (no GPS), no lon/lat
    split = queries.split_queries(
        q["token"].tolist(), int(smk.params.seed), split_fractions(smk.params.split), salt=scene
    )
    q = image_queries.query_table(q, frame, split)
    meta = {
        "scene": scene,
        "source": "images",
        "frame": "local" if frame is None else "gps",
        "crs": None if frame is None else frame.proj4,
        "unit": alignment.get("unit", "m"),
        "views": len(views),
        "min_objects": int(images["min_objects"]),
        "depth_backend": dcfg["backend"],
    }
    io.write_parquet(q, smk.output.queries, meta)
    log.info(
        "scene %s: %d of %d registered images see >= %d objects -> %d queries",
        scene,
        len(q),
        len(views),
        int(images["min_objects"]),
        len(q),
    )


def main(smk, log):
    if smk.params.source == "images":
        images_scene(smk, log)
    else:
        published_scene(smk, log)


runlog.run(main, snakemake)  # noqa: F821
