"""Rule queries: metric GT local maps, normalised depth maps and the split, one row per query."""

from pathlib import Path

import pandas as pd

from flatlandia import geo, io, runlog
from flatlandia.data import localmaps


def main(smk, log):
    scene = smk.wildcards.scene
    ref = pd.read_parquet(smk.input.reference_map)
    meta = io.read_parquet_metadata(smk.input.reference_map)
    frame = geo.MetricFrame(meta["lon0"], meta["lat0"])
    rec = pd.read_parquet(smk.input.recovered)
    local = io.read_local_maps(Path(smk.params.root) / "local_maps.json", scene)
    sp = smk.params.split
    split = localmaps.split_queries(
        list(rec["token"]), smk.params.seed, (sp["train"], sp["val"], sp["test"]), salt=scene
    )
    q = localmaps.build_queries(scene, rec, ref, local, frame, split)
    io.write_parquet(q, smk.output.queries, {**meta, "seed": smk.params.seed, "split": sp})
    log.info("scene %s: %d queries, split %s", scene, len(q), q["split"].value_counts().to_dict())


runlog.run(main, snakemake)  # noqa: F821
