"""Rule coarse_eval: proposals and Table 3 (precision / recall / success) on the test split.

Per loss: results/coarse/{loss}/proposals.parquet, one row per (test query, map type,
strategy) with the proposed reference ``obj_idx`` (columns scene, token, map_type, strategy,
proposal, ...). Table: every loss x strategy x map type, the oracle GT-BB, the training-free
solver's proposals (rule coarse_solver, rows "Solver"), a random-scoring and an S-oracle
baseline, the paper's values beside ours: schema-checked Parquet (``tables.write_table``:
also a flat markdown ``coarse_localization_rows.md`` and LaTeX) and markdown laid out like Table 3.
"""

import pandas as pd
import torch

from flatlandia import checkpoints, io, runlog, tables
from flatlandia.coarse import evaluation, retrieval


def main(smk, log):
    torch.set_num_threads(int(smk.threads))
    losses = list(smk.params.losses)
    models = {}
    for loss, path in zip(losses, smk.input.models):
        models[retrieval.LOSSES[loss]] = checkpoints.load_checkpoint(
            path, retrieval.CoarseConfig, retrieval.build_model
        )
    cfgs = [c for _, c in models.values()]
    graph_keys = ("scale_m", "depth_unit_m", "knn")
    if any(tuple(getattr(c, k) for k in graph_keys) != tuple(getattr(cfgs[0], k) for k in graph_keys) for c in cfgs):
        raise ValueError(
            f"the models were trained with different graph settings {graph_keys}: "
            f"{[tuple(getattr(c, k) for k in graph_keys) for c in cfgs]}"
        )
    scenes = [
        (pd.read_parquet(r), pd.read_parquet(q), pd.read_parquet(s))
        for r, q, s in zip(smk.input.reference_maps, smk.input.queries, smk.input.similarity)
    ]
    ds = retrieval.build_dataset(scenes, cfgs[0], splits=("test",))
    log.info("%d test queries over %d scenes; models %s", len(ds.samples), len(scenes), list(models))
    per_query = evaluation.evaluate(models, ds, "test", baselines=True, seed=int(smk.params.seed))
    solver_rows = pd.read_parquet(smk.input.solver)
    for loss, path in zip(losses, smk.output.proposals):
        rows = per_query[per_query["loss"] == retrieval.LOSSES[loss]].reset_index(drop=True)
        io.write_parquet(
            rows,
            path,
            {"loss": retrieval.LOSSES[loss], "config": models[retrieval.LOSSES[loss]][1].to_dict(), "split": "test"},
        )
    table = evaluation.summarise(pd.concat([per_query, solver_rows], ignore_index=True))
    timing = evaluation.time_one_query(next(iter(models.values()))[0], ds, ds.samples[0]) if ds.samples else {}
    trained = ", ".join(f"{k}: {c.epochs} epochs" for k, (_, c) in models.items())
    c0 = cfgs[0]
    note = (
        f"Ours: test split of every scene; one model per loss trained on GT and depth maps ({trained}; batch "
        f"{c0.batch_size}, Adam lr {c0.lr:g} {c0.lr_schedule}; triplet negatives {100 * c0.hard_negatives:.0f}% "
        "hardest unmatched, the rest random (paper: all random)). "
        "'Solver': no training, the geometric solver's whole-map poses (config `solver`, training-split priors) "
        "place the query's objects; N_LM / 2N_LM: the objects nearest to them, R_30: every object of the "
        "query's classes within 30 m of them, at the best pose and its near-equal alternatives; BB: the "
        "GT-BB box built from the solver's matches and camera. "
        "'random' scores nodes uniformly at random; 'S oracle' ranks by the Sim target itself (needs the GT map). "
    )
    if timing:
        note += (
            f"Scoring one query: {1000 * timing['score_cached_ref_s']:.2f} ms with the scene's reference "
            f"embeddings cached, {1000 * timing['score_with_ref_s']:.2f} ms including them (1 CPU thread). "
        )
    if len(solver_rows):
        ms = (1000 * solver_rows.groupby("map_type")["seconds"].median()).to_dict()
        note += "Solver poses of one query (median): " + ", ".join(f"{k} maps {v:.0f} ms" for k, v in ms.items()) + "."
    # schema-checked Parquet + flat markdown + LaTeX, then the Table-3 layout (ours beside the paper's)
    tables.write_table(
        table,
        "coarse_localization",
        smk.output.table,
        smk.output.rows_markdown,
        smk.output.latex,
        title="Coarse map localization (Table 3): precision / recall / success, test split",
        note=note,
    )
    io.write_text(evaluation.render_markdown(table, note=note), smk.output.markdown)
    log.info("\n%s", table.to_string())


runlog.run(main, snakemake)  # noqa: F821
