"""Rule coarse_solver: training-free region proposals from the geometric solver on the test split.

results/coarse/solver/proposals.parquet: one row per (test query, map type, strategy) with the
proposed reference ``obj_idx`` and its precision / recall / success, the shape of the retrieval
models' proposals (rule coarse_eval merges its rows into Table 3; the fine runs on
``coarse-solver`` read it). The solver is fine_eval's: the same settings (config `solver`) and
the same training-split priors (cameras, co-visibility, and rule solver_priors' scale prior).
"""

import time

import pandas as pd

from flatlandia import solver
from flatlandia.coarse import solver_proposals
from flatlandia.plumbing import files, rule_log


def main(smk, log):
    settings = dict(smk.params["solver"])
    cfg = solver_proposals.SolverProposalConfig.from_dict(smk.params["coarse.solver"])
    solver_cfg = solver.SolverConfig.from_dict(settings)
    learned = solver.LearnedPriors.read(smk.input.solver_priors)
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    solver.warm_up()
    parts = []
    t0 = time.perf_counter()
    for ref, q in scenes:
        cand = solver_proposals.scene_candidates(ref, solver.scene_priors(ref, q, settings, learned))
        test = q[q["split"] == "test"]
        for mt in solver_proposals.MAP_TYPES:
            parts.append(solver_proposals.scene_proposals(ref, test, mt, cand, cfg, solver_cfg))
    rows = pd.concat(parts, ignore_index=True)
    log.info(
        "%d queries x map types in %.1f s", len(rows) // len(solver_proposals.STRATEGIES), time.perf_counter() - t0
    )
    meta = {"loss": solver_proposals.LABEL, "config": cfg.to_dict(), "solver": settings, "split": "test"}
    files.write_parquet(rows, smk.output.proposals, meta)
    summary = rows.groupby(["map_type", "strategy"])[["precision", "recall", "success", "n_proposed"]].mean()
    log.info("\n%s", summary.to_string())


rule_log.run(main, snakemake)  # noqa: F821
