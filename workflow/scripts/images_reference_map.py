"""Rule images_reference_map: an images scene's objects as its reference map (GeoParquet + GeoJSON)."""

import numpy as np
import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia.classes import CLASSES
from flatlandia.data import map_files


def main(smk, log):
    scene = smk.wildcards.scene
    objs = pd.read_parquet(smk.input.objects)
    meta_in = io.read_parquet_metadata(smk.input.objects)
    frame = geo.MetricFrame(lon0=meta_in["lon0"], lat0=meta_in["lat0"])
    objs = objs[objs["class_id"].astype(int) < len(CLASSES)].reset_index(drop=True)
    lonlat = objs[["lon", "lat"]].to_numpy(float).reshape(-1, 2)
    ref = map_files.reference_table(scene, lonlat, objs["class_id"].to_numpy(np.int64), CLASSES, frame)
    ref["object_id"] = objs["object_id"].to_numpy(np.int64)
    meta = {**map_files.frame_metadata(scene, frame), "source": "images: objects from the classified SfM model"}
    map_files.write_geoparquet(ref, meta, smk.output.parquet)
    map_files.write_geojson(ref, meta, smk.output.geojson)
    log.info("scene %s: %d objects on the reference map", scene, len(ref))


runlog.run(main, snakemake)  # noqa: F821
