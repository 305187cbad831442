"""Rule solver_calibration: the solver's fitted priors of one region (rule solver_priors) with the
answers' calibration, fitted on the validation split's answers (single frames and sequences) and
nonsense queries (flatlandia.sequences.validation); a region without a verifier keeps its priors as
fitted (no pool to calibrate)."""

import pandas as pd

from flatlandia.plumbing import rule_log
from flatlandia.sequences import validation
from flatlandia.solver import learned_priors


def main(smk, log):
    fitted = learned_priors.LearnedPriors.read(smk.input.fitted)
    region = smk.wildcards.region
    if region in learned_priors.REGIONS and fitted.verifier is not None:
        scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
        settings, seed = dict(smk.params["solver"]), int(smk.params["seed"])
        fitted, answers = validation.calibrated(scenes, settings, fitted, region, dict(smk.params["beyond"]), seed)
        fitted, evidence = validation.with_null(scenes, settings, fitted, region, seed)
        log.info(
            "calibration on %d validation answers and %d nonsense queries: %s",
            len(answers),
            int((evidence["nonsense"] != "").sum()),
            fitted.calibration.to_dict(),
        )
    else:
        log.info("region %s: no verifier, no pool to calibrate: the priors as fitted", region)
    fitted.write(smk.output.priors)


rule_log.run(main, snakemake)  # noqa: F821
