"""Rule gps_alignment: SfM cameras of an images scene -> the map's ground plane (affine map + residuals).

``images.align.mode: gps`` aligns the cameras to their GPS fixes (metres, lon/lat); ``none``
keeps the SfM frame on its ground plane (photos without GPS: SfM units, no lon/lat).
"""

import numpy as np
import pandas as pd
import pycolmap

from flatlandia import io, runlog
from flatlandia.images import gps_alignment, image_queries


def main(smk, log):
    rec = pycolmap.Reconstruction(smk.input.model)
    views = {v.name: v for v in image_queries.views_from_colmap(rec)}
    cams = pd.read_parquet(smk.input.cameras)
    cams = cams[cams["name"].isin(views)].sort_values("name").reset_index(drop=True)
    p = dict(smk.params.align)
    scene = smk.wildcards.scene
    if p["mode"] == "none":
        out = gps_alignment.local_frame(
            np.array([views[n].centre for n in cams["name"]]).reshape(-1, 3),
            np.array([views[n].R for n in cams["name"]]).reshape(-1, 3, 3),
            unit_m=float(p["unit_m"]),
        )
        method = "camera up axes -> ground plane; local frame, no GPS (images.align.mode: none)"
    else:
        cams, out = gps_alignment.align_camera_table(cams, views, p, smk.params.seed, str(smk.input.cameras), log)
        method = "camera up axes -> ground plane; RANSAC similarity to GPS"
    io.write_json({"scene": scene, "method": method, "cameras": cams["name"].tolist(), **out}, smk.output.json)
    if gps_alignment.is_local(out):
        log.info("scene %s: local frame on the SfM ground plane of %d cameras, unit: %s", scene, len(cams), out["unit"])
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


runlog.run(main, snakemake)  # noqa: F821
