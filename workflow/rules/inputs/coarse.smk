# Input functions and settings of the rules in rules/coarse.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


COARSE = config["coarse"]
#: CPU seconds per coarse training epoch on one core (benchmarks/bench_paper_config.py;
#: docs/measurements.md, "Code paths")
COARSE_EPOCH_S = 1.0


def coarse_train_runtime(wildcards):
    """A coarse_train job's runtime bound in minutes: its epochs x1.5 for a slower node, plus 10."""
    return int(COARSE_EPOCH_S * COARSE["train"]["epochs"] * 1.5 / 60) + 10


def coarse_losses():
    """The losses of this run (config coarse.losses), each one trained model."""
    return list(COARSE["losses"])
