"""Rule sfm: pycolmap on the kept images with masks; clean cameras; final bundle adjustment
(flatlandia.images.sfm.reconstruct)."""

from pathlib import Path

import pandas as pd

from flatlandia.images import sfm
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    """SfM in a scratch folder beside the model, removed whether the reconstruction succeeds or
    fails (killed, the next run's start removes it: flatlandia.plumbing.files.clean_stale_partials)."""
    with files.partial_dir(Path(smk.output.model).parent / "work") as work:
        rec, stats, cameras = sfm.reconstruct(
            Path(smk.input.images),
            pd.read_parquet(smk.input.table),
            Path(smk.input.masks),
            work,
            dict(smk.params["sfm"]),
            smk.params["seed"],
            threads=smk.threads,
            log=log.info,
            native_log=smk.log[0] if smk.log else None,
        )
        with files.atomic_dir(Path(smk.output.model)) as tmp:
            rec.write_binary(str(tmp))
    files.write_parquet(stats, smk.output.stats)
    files.write_parquet(cameras, smk.output.cameras)
    log.info("\n%s", stats.T.to_string())


rule_log.run(main, snakemake)  # noqa: F821
