"""Rule gps_alignment: SfM cameras of an images scene -> the map's ground plane (affine map + residuals;
flatlandia.images.gps_alignment.scene_alignment).

``images.align.mode: gps`` aligns the cameras to their GPS fixes (metres, lon/lat); ``none``
keeps the SfM frame on its ground plane (photos without GPS: SfM units, no lon/lat).
"""

import pandas as pd
import pycolmap

from flatlandia import geo
from flatlandia.images import gps_alignment
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scene = smk.wildcards.scene
    out = gps_alignment.scene_alignment(
        scene,
        pycolmap.Reconstruction(smk.input.model),
        pd.read_parquet(smk.input.cameras),
        dict(smk.params["images.align"]),
        smk.params["seed"],
        source=str(smk.input.cameras),
        log=log,
    )
    files.write_json(out, smk.output.json)
    if geo.alignment_is_local(out):
        log.info(
            "scene %s: local frame on the SfM ground plane of %d cameras, unit: %s",
            scene,
            len(out["cameras"]),
            out["unit"],
        )
        return
    compass = out["compass_median_diff_deg"]
    log.info(
        "scene %s: %d/%d cameras inliers, camera-to-GPS residual median %.2f m (inliers %s m), max %.2f m; "
        "%.3f m per SfM unit; compass vs SfM heading median %s",
        scene,
        out["inliers"],
        out["cameras_with_gps"],
        out["median_residual_m"],
        "n/a" if out["inlier_median_residual_m"] is None else f"{out['inlier_median_residual_m']:.2f}",
        out["max_residual_m"],
        out["metres_per_sfm_unit"],
        "n/a (no headings)" if compass is None else f"{compass:.1f} deg over {out['compass_cameras']} cameras",
    )


rule_log.run(main, snakemake)  # noqa: F821
