# The geometric solver's learned priors (flatlandia.solver.learned): the depth maps' log-scale
# prior, the likelihood ratio's model and the verifier, fitted once per benchmark and region from
# the training split, and the answers' calibration from the validation split; read by fine_eval
# (method solver), coarse_solver, beyond_scene and the city rules.


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
        beyond={k: v for k, v in config["beyond"].items() if k not in ("city_scenes", "city_objects")},
        seed=config["seed"],
    script:
        "../scripts/solver_priors.py"
