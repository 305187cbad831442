"""Rule external_eval: one external method's run (method x map type x proposal) on the test split,
scored from its poses file (config ``external``) with the functions of rule fine_eval
(flatlandia.score: errors by evaluation.error_row, summary by evaluation.summarise)."""

import pandas as pd

from flatlandia import score, vocabulary
from flatlandia.plumbing import rule_log


def main(smk, log):
    w = smk.wildcards
    key = vocabulary.strategy_key(w.proposal)  # a coarse proposal's strategy (config keys in params)
    scenes = {}
    for r, q in zip(smk.input.reference_maps, smk.input.queries):
        s = score.read_scene(r, q)
        scenes[s.scene] = s
    coarse = pd.read_parquet(smk.input.coarse) if smk.input.get("coarse") else None
    strategy = str(smk.params[key]) if key else None
    run, warnings = score.external_run(smk.input.poses, scenes, w.method, w.map_type, w.proposal, coarse, strategy)
    for w in warnings:
        log.warning("%s", w)
    run.write(smk.output.errors, smk.output.summary)
    log.info("%s", run.describe())


rule_log.run(main, snakemake)  # noqa: F821
