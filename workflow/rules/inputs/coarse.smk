# Input functions and settings of the rules in rules/coarse.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


COARSE_LOSSES = ["sim", "trip", "simtrip"]
COARSE = config["coarse"]
# training / baseline seed: the master seed + coarse.seed_offset
COARSE_SEED = int(config["seed"]) + int(COARSE["seed_offset"])
COARSE_TRAIN = {**COARSE["train"], "seed": COARSE_SEED}


def coarse_losses():
    """The losses of this run (config coarse.losses), each one trained model."""
    return list(COARSE["losses"])
