"""Rule export_index: results/export/README.md, classes.csv, scenes.csv and poses_template.csv
(flatlandia.data.export.index_export) over every benchmark scene."""

import pandas as pd

from flatlandia.data import export
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    scenes = [
        {
            "scene": str(scene),
            "city": smk.params.cities[scene],
            "ref": pd.read_parquet(ref),
            "meta": files.read_parquet_metadata(ref),
            "queries": pd.read_parquet(q),
        }
        for scene, ref, q in zip(smk.params.scene_ids, smk.input.reference_maps, smk.input.queries, strict=True)
    ]
    out = export.index_export(scenes, list(smk.params.sources))
    files.write_text(out["readme"], smk.output.readme)
    for name in ("classes", "scenes", "template"):
        files.write_text(export.csv_text(out[name]), smk.output[name])
    absent = [s for s in export.COARSE_SOURCES if s not in smk.params.sources]
    log.info(
        "%d scenes, %d test queries in the template; proposal sources absent: %s",
        len(scenes),
        len(out["template"]),
        ", ".join(absent) or "none",
    )


rule_log.run(main, snakemake)  # noqa: F821
