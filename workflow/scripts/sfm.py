"""Rule sfm: pycolmap on the kept images with masks; clean cameras; final bundle adjustment."""

import shutil
from pathlib import Path

import pandas as pd

from flatlandia import io, runlog, sfm


def main(smk, log):
    import pycolmap

    table = pd.read_parquet(smk.input.table)
    names = list(table.loc[table["kept"], "name"])
    o = dict(smk.params.options)
    opts = sfm.SfmOptions(matcher=o.get("matcher", "exhaustive"), mapper=o.get("mapper", "global"),
                          camera_model=o.get("camera_model", "SIMPLE_RADIAL"),
                          max_image_size=o.get("max_image_size", 1600), seed=smk.params.seed,
                          num_threads=1 if o.get("deterministic", True) else smk.threads, height_mad_k=o.get("height_mad_k", 6.0))
    out = Path(smk.output.model)
    work = out.parent / "work"
    pycolmap.logging.logtostderr = True  # COLMAP's own log, redirected into the rule's log below
    with runlog.native_output_to(smk.log[0]):
        rec = sfm.run_sfm(Path(smk.input.images), names, Path(smk.input.masks), work, opts, log=log.info)
    cams = sfm.camera_centres(rec)
    bad = sfm.height_outliers(cams[["x", "y", "z"]].to_numpy(), opts.height_mad_k)
    removed = cams.loc[bad, ["image_id", "name"]].assign(reason="off the street-level camera plane")
    sfm.remove_cameras(rec, removed["image_id"].tolist())
    log.info("removed %d badly localised cameras; final bundle adjustment", len(removed))
    with runlog.native_output_to(smk.log[0]):
        sfm.final_bundle_adjustment(rec)
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    rec.write_binary(str(tmp))
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    stats = sfm.stats_table(rec, len(names), removed)
    io.write_parquet(stats, smk.output.stats)
    io.write_parquet(sfm.camera_centres(rec).merge(table[["name", "lat", "lon", "alt", "heading"]], on="name"),
                     smk.output.cameras)
    shutil.rmtree(work, ignore_errors=True)
    log.info("\n%s", stats.T.to_string())


runlog.run(main, snakemake)  # noqa: F821
