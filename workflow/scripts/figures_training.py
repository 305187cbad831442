"""Rule figures_training: training curves of every coarse and fine model of the run."""

import pandas as pd

from flatlandia.plumbing import rule_log
from flatlandia.report import figures


def main(smk, log):
    curves = {}
    for label, path in zip(smk.params["coarse.losses"], smk.input.coarse):
        curves[f"coarse {label}"] = pd.read_parquet(path)
    for label, path in zip(smk.params.fine_labels, smk.input.fine):
        curves[f"fine {label}"] = pd.read_parquet(path)
    figures.plot_training_curves(curves, smk.output.png)
    for k, h in curves.items():
        log.info(
            "%s: %d epochs, training loss %.4g -> %.4g", k, len(h), h["train_loss"].iloc[0], h["train_loss"].iloc[-1]
        )


rule_log.run(main, snakemake)  # noqa: F821
