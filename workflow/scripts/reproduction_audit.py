"""Rule reproduction_audit: our objects vs the published reference maps, per scene
(flatlandia.objects.audit: ``audit_objects`` per scene, ``reproduction_table`` over them)."""

import pandas as pd

from flatlandia.data import published
from flatlandia.objects import audit, cloud
from flatlandia.plumbing import rule_log
from flatlandia.report import tables


def main(smk, log):
    rows, panels = [], []
    for scene, obj_path, cloud_path, tr, ref_path in zip(
        smk.params.scene_ids, smk.input.objects, smk.input.clouds, smk.input.transformations, smk.input.reference_maps
    ):
        ours = pd.read_parquet(obj_path)
        row, ref_xy = audit.audit_objects(
            str(scene),
            ours,
            cloud.read_classified_cloud(cloud_path),
            published.read_transformations(tr),
            published.read_reference_map(ref_path),
            radius_m=float(smk.params["objects.audit_radius_m"]),
        )
        rows.append(row)
        title = f"scene {scene}: {row['within_0.5m']}/{row['published']} within 0.5 m"  # escaped where drawn
        panels.append((title, ours[["x_m", "y_m"]].to_numpy(), ref_xy))
        log.info("%s", row)
    df, total, note = audit.reproduction_table(rows, float(smk.params["objects.audit_radius_m"]))
    tables.write_table(
        df,
        "reference_map_reproduction",
        smk.output.parquet,
        smk.output.markdown,
        smk.output.latex,
        title="Reference-map reproduction from the class point clouds",
        note=note,
    )
    audit.plot_audit_grid(panels, smk.output.png)
    log.info(
        "total: %s (%.1f%% within 0.5 m, %.1f%% extra)",
        total,
        100 * total["frac_within_0.5m"],
        100 * total["extra"] / max(1, total["published"]),
    )


rule_log.run(main, snakemake)  # noqa: F821
