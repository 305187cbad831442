"""Rule plot_sfm: top view of an images scene's SfM model, on the map's frame of its alignment record,
beside its GPS track."""

from pathlib import Path

import numpy as np
import pandas as pd
import pycolmap

from flatlandia.images import sfm
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    rec = pycolmap.Reconstruction(smk.input.model)
    cams = pd.read_parquet(smk.input.cameras)
    stats = pd.read_parquet(smk.input.stats).iloc[0]
    pts = np.array([p.xyz for p in rec.points3D.values()])
    alignment = files.read_json(smk.input.alignment)
    sfm.plot_summary(cams, pts, stats, Path(smk.output.png), f"scene {smk.wildcards.scene}", alignment=alignment)
    log.info("wrote %s", smk.output.png)


rule_log.run(main, snakemake)  # noqa: F821
