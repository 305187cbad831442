"""Rule solver_calibration_gt: the priors of GT local maps, their answers' calibration with a null
hypothesis, fitted on the validation split's GT maps and as many nonsense queries in metres
(flatlandia.sequences.validation.gt_calibration); an empty calibration where none fits."""

import pandas as pd

from flatlandia.plumbing import rule_log
from flatlandia.sequences import validation
from flatlandia.solver import learned_priors


def main(smk, log):
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    fitted, evidence = validation.gt_calibration(scenes, dict(smk.params["solver"]), int(smk.params["seed"]))
    real = evidence["nonsense"] == ""
    log.info(
        "GT maps: %d validation answers (%d right) and %d nonsense queries: %s",
        int(real.sum()),
        int(evidence.loc[real, "right"].sum()),
        int((~real).sum()),
        fitted.calibration.to_dict() if fitted is not None else "no calibration fits",
    )
    (fitted or learned_priors.LearnedPriors()).write(smk.output.priors)


rule_log.run(main, snakemake)  # noqa: F821
