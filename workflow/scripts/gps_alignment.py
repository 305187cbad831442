"""Rule gps_alignment: SfM cameras of an images scene -> the map's ground plane (affine map + residuals).

``images.align.mode: gps`` aligns the cameras to their GPS fixes (metres, lon/lat); ``none``
keeps the SfM frame on its ground plane (photos without GPS: SfM units, no lon/lat).
"""

import numpy as np
import pandas as pd
import pycolmap

from flatlandia import io, runlog
from flatlandia.images import gps_alignment, image_queries


def gps_mode(smk, views, cams, p):
    has_gps = cams["lat"].notna() & cams["lon"].notna()
    cams = cams[has_gps].reset_index(drop=True)
    out = gps_alignment.fit_gps_alignment(
        np.array([views[n].centre for n in cams["name"]]).reshape(-1, 3),
        np.array([views[n].R for n in cams["name"]]).reshape(-1, 3, 3),
        cams[["lon", "lat"]].to_numpy(float),
        altitude=cams["alt"].to_numpy(float),
        compass_deg=cams["heading"].to_numpy(float),
        threshold_m=float(p["threshold_m"]),
        iterations=int(p["iterations"]),
        seed=int(smk.params.seed),
        use_heading=bool(p["use_heading"]),
        source=str(smk.input.cameras),
    )
    return cams, out, "camera up axes -> ground plane; RANSAC similarity to GPS"


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
        cams, out, method = gps_mode(smk, views, cams, p)
    io.write_json({"scene": scene, "method": method, "cameras": cams["name"].tolist(), **out}, smk.output.json)
    if gps_alignment.is_local(out):
        log.info("scene %s: local frame on the SfM ground plane of %d cameras, unit: %s", scene, len(cams), out["unit"])
        return
    log.info(
        "scene %s: %d/%d cameras inliers, camera-to-GPS residual median %.2f m (inliers %.2f m), max %.2f m; "
        "%.3f m per SfM unit; compass vs SfM heading median %.1f deg",
        scene,
        out["inliers"],
        out["cameras_with_gps"],
        out["median_residual_m"],
        out["inlier_median_residual_m"],
        out["max_residual_m"],
        out["metres_per_sfm_unit"],
        out.get("compass_median_diff_deg", float("nan")),
    )


runlog.run(main, snakemake)  # noqa: F821
