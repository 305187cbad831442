# The geometric solver's learned priors (flatlandia.solver.learned_priors): the depth maps' noise
# model, log-scale prior, the likelihood ratio's model and the verifier, fitted once per benchmark
# and region from the training split (rule solver_priors: it reads the solver's room and below),
# then the answers' calibration from the validation split (rule solver_calibration: it solves the
# validation queries, single frames and sequences, with the fitted priors); the calibrated priors
# are read by fine_eval (method solver), coarse_solver, beyond_scene and the city rules.


include: "inputs/solver.smk"


rule solver_priors:
    input:
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
    output:
        priors=paths.solver_fit(),
    log:
        "logs/solver_priors/{region}.log",
    benchmark:
        "logs/benchmarks/solver_priors/{region}.tsv"
    wildcard_constraints:
        region="|".join(vocabulary.PRIOR_REGIONS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("solver_priors")
    resources:
        **rule_resources("solver_priors"),
    params:
        **config_keys("solver"),
    script:
        "../scripts/solver_priors.py"


rule solver_calibration:
    input:
        fitted=paths.solver_fit(),
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
    output:
        priors=paths.solver_priors(),
    log:
        "logs/solver_calibration/{region}.log",
    benchmark:
        "logs/benchmarks/solver_calibration/{region}.tsv"
    wildcard_constraints:
        region="|".join(vocabulary.PRIOR_REGIONS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("solver_calibration")
    resources:
        **rule_resources("solver_calibration"),
    params:
        **config_keys("solver", "beyond", "seed", exclude=BEYOND_CITIES),
    script:
        "../scripts/solver_calibration.py"


# GT local maps (metres) learn nothing from the training split; their answers' probability is
# calibrated on the validation split's GT maps and nonsense queries in metres, with a null hypothesis
rule solver_calibration_gt:
    input:
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
    output:
        priors=paths.solver_priors_gt(),
    log:
        "logs/solver_calibration_gt/{region}.log",
    benchmark:
        "logs/benchmarks/solver_calibration_gt/{region}.tsv"
    wildcard_constraints:
        region=vocabulary.WHOLE,
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("solver_calibration_gt")
    resources:
        **rule_resources("solver_calibration_gt"),
    params:
        **config_keys("solver", "seed"),
    script:
        "../scripts/solver_calibration_gt.py"
