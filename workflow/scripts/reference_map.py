"""Rule reference_map: the published map of a scene as GeoParquet + GeoJSON in a metric frame."""

from pathlib import Path

from flatlandia import geo, io, runlog
from flatlandia.classes import CLASSES
from flatlandia.data import map_files


def main(smk, log):
    scene = smk.wildcards.scene
    lonlat, classes = io.read_reference_map(
        Path(smk.params.root) / f"individual_reference_maps/map_{scene}.json", n_classes=len(CLASSES)
    )
    frame = geo.frame_for(lonlat)
    ref = map_files.reference_table(scene, lonlat, classes, CLASSES, frame)
    meta = map_files.frame_metadata(scene, frame)
    map_files.write_geoparquet(ref, meta, smk.output.parquet)
    map_files.write_geojson(ref, meta, smk.output.geojson)
    log.info("scene %s: %d objects, %d classes, frame %s", scene, len(ref), ref["class_id"].nunique(), frame.proj4)


runlog.run(main, snakemake)  # noqa: F821
