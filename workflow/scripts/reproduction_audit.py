"""Rule reproduction_audit: our objects vs the published reference maps, per scene."""

import pandas as pd

from flatlandia import geo, io, runlog, tables
from flatlandia.objects import clustering


def main(smk, log):
    rows, panels = [], []
    for scene, obj_path, cloud, tr, ref_path in zip(
        smk.params.scenes, smk.input.objects, smk.input.clouds, smk.input.transformations, smk.input.reference_maps
    ):
        ours = pd.read_parquet(obj_path)
        ref_ll, ref_cl = io.read_reference_map(ref_path)
        frame = geo.frame_for(ref_ll)
        pts, labels = clustering.read_classified_cloud(cloud)
        t = io.read_transformations(tr)
        fg = labels != clustering.BACKGROUND
        ref_xy = frame.to_xy(ref_ll)
        ref_macro = clustering.published_macro_classes(
            ref_xy,
            ref_cl,
            frame.to_xy(geo.sfm_to_lonlat(pts[fg], t)),
            labels[fg],
            cloud_points=pts[fg],
            exact_radius=clustering.EXACT_SEARCH_RADIUS_M / clustering.metres_per_unit(t),
        )
        ours_xy = ours[["x_m", "y_m"]].to_numpy()
        row = clustering.audit_scene(
            str(scene), ours_xy, ours["macro_class"].to_numpy(), ref_xy, ref_macro, radius_m=float(smk.params.radius_m)
        )
        rows.append(row)
        panels.append((f"scene {scene}: {row['within_0.5m']}/{row['published']} within 0.5 m", ours_xy, ref_xy))
        log.info("%s", row)
    df = pd.DataFrame(rows)
    counts = ["published", "ours", "matched", "within_0.05m", "within_0.5m", "within_2m", "extra"]
    total = {
        "scene": "all",
        **{c: int(df[c].sum()) for c in counts},
        "median_dist_m": float(df["median_dist_m"].median()) if len(df) else float("nan"),
    }
    total["frac_within_0.5m"] = total["within_0.5m"] / max(1, total["published"])
    df = pd.concat([df, pd.DataFrame([total])], ignore_index=True)
    df = df[[c.name for c in tables.SCHEMAS["reference_map_reproduction"]]]
    note = (
        f"Our objects (clusters of the published class point clouds) matched to the published reference maps, "
        f"same macro-class, Hungarian within {float(smk.params.radius_m):g} m; 'all' sums the scenes "
        f"(its median_dist_m is the median of the scenes'). Targets: frac_within_0.5m >= 0.9, extra <= 10% of "
        f"published."
    )
    tables.write_table(
        df,
        "reference_map_reproduction",
        smk.output.parquet,
        smk.output.markdown,
        smk.output.latex,
        title="Reference-map reproduction from the class point clouds",
        note=note,
    )
    clustering.plot_audit_grid(panels, smk.output.png)
    log.info(
        "total: %s (%.1f%% within 0.5 m, %.1f%% extra)",
        total,
        100 * total["frac_within_0.5m"],
        100 * total["extra"] / max(1, total["published"]),
    )


runlog.run(main, snakemake)  # noqa: F821
