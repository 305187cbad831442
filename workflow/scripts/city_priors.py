"""Rule city_priors: the solver's depth scale prior and verifier from the benchmark scenes'
training split (flatlandia.city.priors), shared by every city size and both methods."""

import pandas as pd

from flatlandia import io, runlog
from flatlandia.city import priors


def main(smk, log):
    scenes = [(pd.read_parquet(r), pd.read_parquet(q)) for r, q in zip(smk.input.reference_maps, smk.input.queries)]
    fitted = priors.fit(scenes, dict(smk.params.geo))
    log.info("priors: %s", fitted)
    io.write_json(fitted, smk.output.priors)


runlog.run(main, snakemake)  # noqa: F821
