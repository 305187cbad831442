"""Rule reference_map: a scene's reference map as GeoParquet + GeoJSON in its metric frame.

A published scene's map is the published one; an images scene's map is its objects (those
with a 42-class label), in the metric frame of its GPS alignment.
"""

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia.classes import CLASSES
from flatlandia.data import reference_map


def published_scene(smk, log):
    scene = smk.wildcards.scene
    lonlat, classes = io.read_reference_map(
        Path(smk.params.root) / f"individual_reference_maps/map_{scene}.json", n_classes=len(CLASSES)
    )
    frame = geo.frame_for(lonlat)
    ref = reference_map.reference_table(scene, lonlat, classes, CLASSES, frame)
    meta = reference_map.frame_metadata(scene, frame)
    reference_map.write_geoparquet(ref, meta, smk.output.parquet)
    reference_map.write_geojson(ref, meta, smk.output.geojson)
    log.info("scene %s: %d objects, %d classes, frame %s", scene, len(ref), ref["class_id"].nunique(), frame.proj4)


def images_scene(smk, log):
    scene = smk.wildcards.scene
    objs = pd.read_parquet(smk.input.objects)
    meta_in = io.read_parquet_metadata(smk.input.objects)
    objs = objs[objs["class_id"].astype(int) < len(CLASSES)].reset_index(drop=True)
    lonlat = objs[["lon", "lat"]].to_numpy(float).reshape(-1, 2)
    xy = objs[["x_m", "y_m"]].to_numpy(float).reshape(-1, 2)
    if meta_in.get("frame") == "local":  # photos without GPS: the SfM ground plane, no lon/lat
        frame, frame_meta = None, reference_map.local_frame_metadata(scene, meta_in["unit"])
    else:
        frame = geo.MetricFrame(lon0=meta_in["lon0"], lat0=meta_in["lat0"])
        frame_meta = reference_map.frame_metadata(scene, frame)
    ref = reference_map.reference_table(scene, lonlat, objs["class_id"].to_numpy(np.int64), CLASSES, frame, xy)
    ref["object_id"] = objs["object_id"].to_numpy(np.int64)
    meta = {**frame_meta, "source": "images: objects from the classified SfM model"}
    reference_map.write_geoparquet(ref, meta, smk.output.parquet)
    reference_map.write_geojson(ref, meta, smk.output.geojson)
    log.info("scene %s: %d objects on the reference map", scene, len(ref))


def main(smk, log):
    if smk.params.source == "images":
        images_scene(smk, log)
    else:
        published_scene(smk, log)


runlog.run(main, snakemake)  # noqa: F821
