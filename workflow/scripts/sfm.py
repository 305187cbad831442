"""Rule sfm: pycolmap on the kept images with masks; clean cameras; final bundle adjustment."""

from pathlib import Path

import numpy as np
import pandas as pd

from flatlandia import io, runlog
from flatlandia.images import gps_alignment, image_queries, sfm


def main(smk, log):
    """SfM in a scratch folder beside the model, removed whether the reconstruction succeeds or
    fails (killed, the next run's start removes it: flatlandia.io.clean_stale_partials)."""
    with io.partial_dir(Path(smk.output.model).parent / "work") as work:
        reconstruct(smk, log, work)


def reconstruct(smk, log, work: Path):
    import pycolmap

    table = pd.read_parquet(smk.input.table)
    names = list(table.loc[table["kept"], "name"])
    o = dict(smk.params.options)
    opts = sfm.SfmOptions(
        matcher=o["matcher"],
        mapper=o["mapper"],
        camera_model=o["camera_model"],
        max_image_size=o["max_image_size"],
        seed=smk.params.seed,
        num_threads=1 if o["deterministic"] else smk.threads,
        height_mad_k=o["height_mad_k"],
    )
    out = Path(smk.output.model)
    pycolmap.logging.logtostderr = True  # COLMAP's own log, redirected into the rule's log below
    with runlog.native_output_to(smk.log[0]):
        rec = sfm.run_sfm(Path(smk.input.images), names, Path(smk.input.masks), work, opts, log=log.info)
    cams = sfm.camera_centres(rec)
    bad = sfm.height_outliers(cams[["x", "y", "z"]].to_numpy(), opts.height_mad_k)
    removed = cams.loc[bad, ["image_id", "name"]].assign(reason="off the street-level camera plane")
    # cameras far from their own GPS fix once the model is aligned to GPS (flatlandia.images.gps_alignment: up axes + RANSAC)
    views = {v.name: v for v in image_queries.views_from_colmap(rec)}
    kept = cams.loc[~bad].reset_index(drop=True)
    gps = table.set_index("name").reindex(kept["name"])[["lon", "lat"]].to_numpy(float)
    far = gps_alignment.gps_outliers(
        kept[["x", "y", "z"]].to_numpy(),
        np.array([views[n].R for n in kept["name"]]),
        gps,
        float(o["gps_max_residual_m"]),
        seed=int(smk.params.seed),
    )
    removed = pd.concat(
        [
            removed,
            kept.loc[far, ["image_id", "name"]].assign(
                reason=f"over {o['gps_max_residual_m']} m from its GPS fix after aligning the model to GPS"
            ),
        ]
    )
    sfm.remove_cameras(rec, removed["image_id"].tolist())
    log.info("removed %d badly localised cameras; final bundle adjustment", len(removed))
    with runlog.native_output_to(smk.log[0]):
        priors, frame = (
            sfm.gps_priors(
                rec,
                table.set_index("name"),
                float(o["gps_prior_sigma_m"]),
                float(o["gps_prior_alt_sigma_m"]),
            )
            if o["gps_prior"]
            else ([], None)
        )
        used = sfm.final_bundle_adjustment(rec, priors, seed=int(smk.params.seed))
    with io.atomic_dir(out) as tmp:
        rec.write_binary(str(tmp))
    stats = sfm.stats_table(rec, len(names), removed)
    stats["gps_prior_images"] = len(priors) if used else 0
    stats["model_frame"] = (
        (f"metric, x east / y north / z up (m) around lon {frame.lon0}, lat {frame.lat0} (aligned to the GPS priors)")
        if used
        else "arbitrary SfM frame (no GPS priors)"
    )
    log.info("final bundle adjustment %s", f"with {len(priors)} GPS position priors" if used else "without priors")
    io.write_parquet(stats, smk.output.stats)
    io.write_parquet(
        sfm.camera_centres(rec).merge(table[["name", "lat", "lon", "alt", "heading"]], on="name"), smk.output.cameras
    )
    log.info("\n%s", stats.T.to_string())


runlog.run(main, snakemake)  # noqa: F821
