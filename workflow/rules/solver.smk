# The geometric solver's learned priors (flatlandia.solver.learned): the depth maps' log-scale
# prior and the verifier, fitted once per benchmark and region from the training split, read by
# fine_eval (method solver), coarse_solver and the city rules.


include: "inputs/solver.smk"


rule solver_priors:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
    output:
        priors="results/solver/priors/{region}.json",
    log:
        "logs/solver_priors/{region}.log",
    benchmark:
        "logs/benchmarks/solver_priors/{region}.tsv"
    wildcard_constraints:
        region="|".join(SOLVER_PRIOR_REGIONS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("solver_priors")
    resources:
        **rule_resources("solver_priors"),
    params:
        solver=config["solver"],
    script:
        "../scripts/solver_priors.py"
