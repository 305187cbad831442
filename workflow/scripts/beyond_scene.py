"""Rule beyond_scene: every test anchor's sequences and GPS fixes on its scene's whole map, with the
camera prior {prior} (flatlandia.sequences.evaluation.scene_errors); per-anchor errors and the summary
rows of the table beyond_one_frame."""

import numpy as np
import pandas as pd

from flatlandia import solver
from flatlandia.plumbing import files, rule_log
from flatlandia.plumbing.files import json_safe
from flatlandia.sequences import evaluation


def main(smk, log):
    beyond = dict(smk.params["beyond"])
    camera = smk.wildcards.prior == "on"
    refs = [pd.read_parquet(p) for p in smk.input.reference_maps]
    scenes = list(zip(refs, [pd.read_parquet(p) for p in smk.input.queries]))
    settings = evaluation.settings_grid(beyond, camera)
    log.info("settings: %s", settings)
    errors = evaluation.scene_errors(
        scenes,
        settings,
        dict(smk.params["solver"]),
        beyond,
        solver.LearnedPriors.read(smk.input.priors),
        int(smk.params["seed"]),
        beyond["split"],
        log=log,
    )
    rows = evaluation.summaries(errors, {"scene": int(round(np.mean([len(r) for r in refs])))})
    files.write_parquet(errors, smk.output.errors, {"split": beyond["split"], "beyond": beyond})
    files.write_json([json_safe(r) for r in rows], smk.output.summary)
    for r in rows:
        log.info("%s", r)


rule_log.run(main, snakemake)  # noqa: F821
