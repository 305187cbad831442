# Input functions and settings of the rules in rules/solver.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.
#
# The regions the solver's priors are fitted for (vocabulary.PRIOR_REGIONS): a verifier learns on the
# whole map or on the GT-BB box (the region the test queries get); `scale` holds the scale prior alone
# (the regions no verifier learns on: coarse proposals, the coarse stage's own solver). Which region
# a run on a proposal reads: vocabulary.prior_region, paths.proposal_priors.

#: the keys of config `beyond` that name the city rows' maps, not the protocol: the rules that read
#: the protocol leave them out, so another city does not rerun them
BEYOND_CITIES = ["beyond.city_scenes", "beyond.city_objects"]
