"""Rule principal_plane: our principal plane of a published class cloud vs the published one
(flatlandia.objects.principal_plane.published_plane_report).

Published scenes carry no camera GPS, so their SfM -> map transform is the published chain
(recorded here as a metric 2D transform); the robust GPS fit of the images scenes
(:func:`flatlandia.scaled_rigid.ransac_scaled_rigid`) is exercised on scene 12 in
tests/test_align.py.
"""

from flatlandia.data import published
from flatlandia.objects import cloud, principal_plane
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    pts, labels = cloud.read_classified_cloud(smk.input.cloud)
    out = principal_plane.published_plane_report(
        smk.wildcards.scene,
        pts,
        labels,
        published.read_transformations(smk.input.transformations),
        max_points=int(smk.params["objects.principal_plane.max_points"]),
        min_ground_points=int(smk.params["objects.principal_plane.min_ground_points"]),
        ground_scale_m=float(smk.params["objects.principal_plane.ground_scale_m"]),
        fallback_scale_m=float(smk.params["objects.principal_plane.fallback_scale_m"]),
        source=str(smk.input.cloud),
    )
    files.write_json(out, smk.output.json)
    log.info(
        "scene %s: plane angle to published %.2f deg; Rpp reflection %s, R2 reflection %s",
        out["scene"],
        out["plane_angle_deg"],
        out["published_rpp_is_reflection"],
        out["published_r2_is_reflection"],
    )


rule_log.run(main, snakemake)  # noqa: F821
