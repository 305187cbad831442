"""Rule principal_plane: our principal plane of a published class cloud vs the published one.

Published scenes carry no camera GPS, so their SfM -> map transform is the published chain
(recorded here as a metric 2D transform); the robust GPS fit of the images scenes
(:func:`flatlandia.scaled_rigid.ransac_scaled_rigid`) is exercised on scene 12 in
tests/test_align.py.
"""

import numpy as np

from flatlandia import geo, io, runlog
from flatlandia.objects import cloud, principal_plane


def main(smk, log):
    scene = smk.wildcards.scene
    pts, labels = cloud.read_classified_cloud(smk.input.cloud)
    t = io.read_transformations(smk.input.transformations)
    step = max(1, len(pts) // int(smk.params.max_points))
    # street plane through the ground classes (Cauchy IRLS, lengths in metres; see fit_ground_plane)
    plane, plane_points = principal_plane.fit_ground_plane(
        pts,
        labels,
        cloud.metres_per_unit(t),
        min_ground_points=int(smk.params.min_ground_points),
        ground_scale_m=float(smk.params.ground_scale_m),
        fallback_scale_m=float(smk.params.fallback_scale_m),
        source=str(smk.input.cloud),
    )
    rpp = np.asarray(t["to_principal_plane"], float)
    r2 = np.asarray(t["to_mapillary"]["rotation"], float)
    pub_n = principal_plane.published_normal(rpp)
    angle = principal_plane.normal_angle_deg(plane.normal, pub_n)
    # frame on the median point: clouds hold far outliers that a bounding-box centre would follow
    med = np.median(geo.sfm_to_lonlat(pts[::step], t), axis=0)
    frame = geo.MetricFrame(lon0=round(float(med[0]), 7), lat0=round(float(med[1]), 7))
    chain = principal_plane.published_chain_transform(t, frame, pts[::step])
    out = {
        "scene": scene,
        "method": "published chain (no camera GPS in the published data)",
        "plane_source": f"class point cloud, {plane_points} (Cauchy IRLS)",
        "plane_normal": plane.normal.tolist(),
        "plane_inlier_fraction": float(plane.inliers.mean()),
        "published_normal": pub_n.tolist(),
        "plane_angle_deg": angle,
        "published_rpp_is_reflection": bool(np.linalg.det(rpp) < 0),
        "published_r2_is_reflection": bool(np.linalg.det(r2) < 0),
        "metres_per_sfm_unit": cloud.metres_per_unit(t),
        "chain_metric_scale_m_per_unit": chain.scale,
        "chain_rotation_deg": chain.angle_deg(),
        "chain_is_reflection": chain.reflection,
        "our_plane_rotation": principal_plane.plane_rotation(plane.normal).tolist(),
    }
    io.write_json(out, smk.output.json)
    log.info(
        "scene %s: plane angle to published %.2f deg; Rpp reflection %s, R2 reflection %s",
        scene,
        angle,
        out["published_rpp_is_reflection"],
        out["published_r2_is_reflection"],
    )


runlog.run(main, snakemake)  # noqa: F821
