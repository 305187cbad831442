"""Rule reproduction_audit: our objects vs the published reference maps, per scene."""

import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia import objects as O


def main(smk, log):
    rows, panels = [], []
    for scene, obj_path, cloud, tr, ref_path in zip(smk.params.scenes, smk.input.objects, smk.input.clouds,
                                                      smk.input.transformations, smk.input.reference_maps):
        ours = pd.read_parquet(obj_path)
        ref_ll, ref_cl = io.read_reference_map(ref_path)
        frame = geo.frame_for(ref_ll)
        pts, labels = O.read_classified_cloud(cloud)
        t = io.read_transformations(tr)
        fg = labels != O.BACKGROUND
        ref_xy = frame.to_xy(ref_ll)
        ref_macro = O.published_macro_classes(ref_xy, ref_cl, frame.to_xy(geo.sfm_to_lonlat(pts[fg], t)), labels[fg])
        ours_xy = ours[["x_m", "y_m"]].to_numpy()
        row = O.audit_scene(str(scene), ours_xy, ours["macro_class"].to_numpy(), ref_xy, ref_macro,
                            radius_m=float(smk.params.radius_m))
        rows.append(row)
        panels.append((f"scene {scene}: {row['within_0.5m']}/{row['published']} within 0.5 m", ours_xy, ref_xy))
        log.info("%s", row)
    df = pd.DataFrame(rows)
    tot = {"published": int(df["published"].sum()), "ours": int(df["ours"].sum()),
           "within_0.5m": int(df["within_0.5m"].sum()), "extra": int(df["extra"].sum())}
    io.write_parquet(df, smk.output.parquet, {"radius_m": float(smk.params.radius_m), "totals": tot,
                                              "matching": "same macro-class, Hungarian on metric distance"})
    O.plot_audit_grid(panels, smk.output.png)
    log.info("total: %s (%.1f%% within 0.5 m, %.1f%% extra)", tot, 100 * tot["within_0.5m"] / max(1, tot["published"]),
             100 * tot["extra"] / max(1, tot["published"]))


runlog.run(main, snakemake)  # noqa: F821
