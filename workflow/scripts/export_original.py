"""Rule export_original: the benchmark in the authors' own form under results/export/original/
(data/flatlandia.json, data/region_proposal.json, data/local_maps.json, README.md), read back and
checked as their code reads them before it is moved into place (flatlandia.data.original)."""

from pathlib import Path

import pandas as pd

from flatlandia.data import original
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.errors import InputError


def main(smk, log):
    folder = Path(smk.output.readme).parent
    for name, rel in original.FILES.items():
        if Path(smk.output[name]) != folder / rel:
            raise InputError(smk.output[name], f"rule export_original's output {name} is not {folder / rel}")
    scenes = [
        {
            "scene": str(scene),
            "ref": pd.read_parquet(ref),
            "meta": files.read_parquet_metadata(ref),
            "recovered": pd.read_parquet(rec),
            "queries": pd.read_parquet(q),
            "queries_meta": files.read_parquet_metadata(q),
        }
        for scene, ref, rec, q in zip(
            smk.params.scene_ids, smk.input.reference_maps, smk.input.recovered, smk.input.queries, strict=True
        )
    ]
    sources = list(smk.params.sources)
    coarse = {s: pd.read_parquet(p) for s, p in zip(sources, smk.input.proposals, strict=True)}
    local_maps = Path(smk.input.local_maps)
    out = original.original_export(scenes, coarse, files.read_json(local_maps), local_maps)
    original.write(folder, out, reads=[local_maps])
    rp = out["region_proposal"]["GT"]["all"]
    log.info(
        "%d maps, %d queries; region proposals (GT, all): %s; absent sources: %s",
        len(out["flatlandia"]["maps"]),
        len(out["flatlandia"]["miscellanea"]["split"]["img_to_scene"]),
        {k: len(v) for k, v in rp.items()},
        ", ".join(s for s in original.SOURCES if s not in coarse) or "none",
    )


rule_log.run(main, snakemake)  # noqa: F821
