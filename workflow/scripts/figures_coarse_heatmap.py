"""Rule figures_coarse_heatmap: every coarse model's scores for one test query over its reference map."""

import pandas as pd
import torch

from flatlandia import checkpoints
from flatlandia.coarse import retrieval
from flatlandia.plumbing import rule_log
from flatlandia.report import figures


def main(smk, log):
    torch.set_num_threads(1)
    ref, q, sim = (pd.read_parquet(p) for p in (smk.input.reference_map, smk.input.queries, smk.input.similarity))
    models = {
        retrieval.LOSSES[loss]: checkpoints.load_checkpoint(p, retrieval.CoarseTrainConfig, retrieval.build_model)
        for loss, p in zip(smk.params["coarse.losses"], smk.input.models)
    }
    cfg0 = next(iter(models.values()))[1]
    ds = retrieval.build_dataset([(ref, q, sim)], cfg0, splits=("test",))
    if not ds.samples:
        ds = retrieval.build_dataset([(ref, q, sim)], cfg0, splits=("train", "val", "test"))
    sample = sorted(ds.samples, key=lambda s: (-s.n_objects, s.token))[0]
    mt = smk.params["report.heatmap_map_type"]
    scores = {label: retrieval.score_samples(model, ds, [sample], mt)[0] for label, (model, _) in models.items()}
    row = q.set_index(q["token"].astype(str)).loc[sample.token]
    figures.plot_score_heatmap(
        ds.refs[0],
        scores,
        sample.positives,
        row[["x_m", "y_m"]].to_numpy(float),
        float(row["theta_deg"]),
        smk.output.png,
        f"scene {smk.wildcards.scene}, query {sample.token} ({sample.split}, "
        f"{sample.n_objects} objects, {mt} local map)",
    )
    log.info(
        "scene %s query %s: %d reference objects scored by %s",
        smk.wildcards.scene,
        sample.token,
        len(ref),
        list(scores),
    )


rule_log.run(main, snakemake)  # noqa: F821
