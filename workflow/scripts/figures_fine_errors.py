"""Rule figures_fine_errors: error CDFs per fine run and the paper's Fig. 8 (error vs objects, classes)."""

import numpy as np
import pandas as pd

from flatlandia.plumbing import rule_log
from flatlandia.report import figures


def main(smk, log):
    classes = {}
    for path in smk.input.queries:
        q = pd.read_parquet(path, columns=["scene", "token", "classes"])
        classes.update({(str(s), str(t)): len(set(np.asarray(c).tolist())) for s, t, c in q.itertuples(index=False)})
    errors = {}
    for run, path in zip(smk.params.runs, smk.input.errors):
        e = pd.read_parquet(path)
        e["n_classes"] = [classes.get((str(s), str(t)), np.nan) for s, t in zip(e["scene"], e["token"])]
        errors[run] = e
        log.info(
            "%s: %d queries, median %.2f m / %.2f deg", run, len(e), e["error_m"].median(), e["error_deg"].median()
        )
    figures.plot_error_cdfs(errors, smk.output.cdf)
    figures.plot_error_vs_objects(errors, smk.output.vs_objects)


rule_log.run(main, snakemake)  # noqa: F821
