"""Rule solver_priors: the solver's learned priors of depth maps (scale prior, verifier) from the
benchmark scenes' training split, for one region (flatlandia.solver.learned)."""

import pandas as pd

from flatlandia import runlog
from flatlandia.solver import learned, verify


def main(smk, log):
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    region = smk.wildcards.region
    fitted = learned.fit(scenes, dict(smk.params.solver), region if region in learned.REGIONS else None)
    log.info("depth scale prior (log metres per unit): %s", fitted.scale)
    if fitted.verifier is not None:
        weights = {f: round(float(w), 3) for f, w in zip(verify.FEATURES, fitted.verifier.weights)}
        log.info("verifier on %s, weights of the standardised features: %s", region, weights)
    fitted.write(smk.output.priors)


runlog.run(main, snakemake)  # noqa: F821
