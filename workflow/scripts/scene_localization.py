"""Rule scene_localization: an images scene's queries localized by the benchmark's methods."""

from pathlib import Path

import pandas as pd
import torch

from flatlandia import checkpoints
from flatlandia.fine import models, scene_localization
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    scene = smk.wildcards.scene
    ref, queries = pd.read_parquet(smk.input.reference_map), pd.read_parquet(smk.input.queries)
    meta = {"scene": scene, "models": [str(p) for p in smk.input.checkpoints], "retrained": False}
    if len(queries) == 0:
        meta["empty_because"] = "the scene has no query, so nothing is evaluated (see results/summary.md)"
        log.warning("scene %s: %s", scene, meta["empty_because"])
    loaded = {}
    for path in smk.input.checkpoints:
        model, cfg = checkpoints.load_checkpoint(path, models.FineTrainConfig, models.build_model)
        slug = Path(path).parent.name.rsplit("_", 2)[0]  # {model}_{map_type}_{train}
        loaded[(slug, cfg.map_type)] = (model, cfg)
    rows = scene_localization.scene_rows(
        ref,
        queries,
        loaded,
        list(smk.params["fine.runs.map_types"]),
        dict(smk.params["solver"]),
        progress=rule_log.progress(log, f"scene {scene}"),
    )
    files.write_parquet(rows, smk.output.parquet, meta)
    files.write_text(scene_localization.render_markdown(rows, scene), smk.output.markdown)
    log.info(
        "scene %s: %d queries, %d rows\n%s",
        scene,
        len(queries),
        len(rows),
        scene_localization.render_markdown(rows, scene),
    )


rule_log.run(main, snakemake)  # noqa: F821
