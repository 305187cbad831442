"""Rule coarse_eval: proposals and Table 3 (precision / recall / success) on the test split
(flatlandia.coarse.evaluation.evaluate_models).

Per loss: results/coarse/{loss}/proposals.parquet, one row per (test query, map type,
strategy) with the proposed reference ``obj_idx`` (columns scene, token, map_type, strategy,
proposal, ...). Table: every loss x strategy x map type, the oracle GT-BB, the training-free
solver's proposals (rule coarse_solver, rows "Solver"), a random-scoring and an S-oracle
baseline, the paper's values beside ours: schema-checked Parquet (``tables.write_table``:
also a flat markdown ``coarse_localization_rows.md`` and LaTeX) and markdown laid out like Table 3.
"""

import pandas as pd
import torch

from flatlandia import checkpoints
from flatlandia import device as device_module
from flatlandia.coarse import evaluation, retrieval
from flatlandia.plumbing import files, rule_log
from flatlandia.report import tables


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    device = device_module.resolve(smk.config["device"])  # a cuda without a GPU stops here, one line
    log.info("device: %s", device_module.describe(device))
    losses = list(smk.params["coarse.losses"])
    seed = int(smk.params["seed"]) + int(smk.params["coarse.seed_offset"])  # the random baseline's, as training's
    models = {
        retrieval.LOSSES[loss]: checkpoints.load_checkpoint(path, retrieval.CoarseTrainConfig, retrieval.build_model)
        for loss, path in zip(losses, smk.input.models)
    }
    scenes = [
        (pd.read_parquet(r), pd.read_parquet(q), pd.read_parquet(s))
        for r, q, s in zip(smk.input.reference_maps, smk.input.queries, smk.input.similarity)
    ]
    solver_rows = pd.read_parquet(smk.input.solver)
    out = evaluation.evaluate_models(models, scenes, solver_rows, seed, log, device=device)
    for loss, path in zip(losses, smk.output.proposals):
        label = retrieval.LOSSES[loss]
        files.write_parquet(
            out.proposals[label], path, {"loss": label, "config": models[label][1].to_dict(), "split": "test"}
        )
    # schema-checked Parquet + flat markdown + LaTeX, then the Table-3 layout (ours beside the paper's)
    tables.write_table(
        out.table,
        "coarse_localization",
        smk.output.table,
        smk.output.rows_markdown,
        smk.output.latex,
        title="Coarse map localization (Table 3): precision / recall / success, test split",
        note=out.note,
    )
    files.write_text(evaluation.render_markdown(out.table, note=out.note), smk.output.markdown)
    log.info("\n%s", out.table.to_string())


rule_log.run(main, snakemake)  # noqa: F821
