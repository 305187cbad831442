# Input functions and settings of the rules in rules/solver.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.

#: the regions the solver's priors are fitted for: a verifier learns on the whole map or on the
#: GT-BB box (the region the test queries get); `scale` holds the scale prior alone (the regions
#: no verifier learns on: coarse proposals, the coarse stage's own solver)
SOLVER_PRIOR_REGIONS = ["whole", "gtbb", "scale"]


def solver_priors_file(proposal):
    """The learned priors a depth-map run on ``proposal`` reads (rule solver_priors)."""
    region = proposal if proposal in ("whole", "gtbb") else "scale"
    return f"results/solver/priors/{region}.json"
