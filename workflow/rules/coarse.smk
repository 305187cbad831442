# Coarse map localization: the neighbourhood similarity target per scene -> one GAT per loss
# (Sim | Trip | Sim+Trip) over every scene's train split -> proposals (N_LM | 2N_LM | R_30 | GT-BB)
# and Table 3 on the test split; beside them the training-free proposals of the geometric solver
# (coarse_solver, rows "Solver" of Table 3). Settings: the `coarse:` section of config/config.yaml
# (a short default run); config/paper.yaml has the paper's 800 epochs. No lambdas in rules.


include: "inputs/coarse.smk"


rule coarse_target:
    input:
        reference_map=paths.reference_map(),
        queries=paths.queries(),
    output:
        similarity=paths.coarse_target(),
    log:
        "logs/coarse_target/{scene}.log",
    benchmark:
        "logs/benchmarks/coarse_target/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("coarse_target")
    resources:
        **rule_resources("coarse_target"),
    params:
        **config_keys("coarse.similarity"),
    script:
        "../scripts/coarse_target.py"


rule coarse_train:
    input:
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
        similarity=per_scene(paths.coarse_target(), benchmark_scenes()),
    output:
        model=paths.coarse_model(),
        history=paths.coarse_training(),
    log:
        "logs/coarse_train/{loss}.log",
    benchmark:
        "logs/benchmarks/coarse_train/{loss}.tsv"
    wildcard_constraints:
        loss="|".join(vocabulary.COARSE_LOSSES),
    priority: 1
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("coarse_train")
    resources:
        **rule_resources("coarse_train"),
    params:
        **config_keys("coarse.train", "coarse.seed_offset", "seed"),
    script:
        "../scripts/coarse_train.py"


rule coarse_solver:
    input:
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
        solver_priors=paths.solver_priors("scale"),
    output:
        proposals=paths.coarse_proposals("solver"),
    log:
        "logs/coarse_solver/all.log",
    benchmark:
        "logs/benchmarks/coarse_solver/all.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("coarse_solver")
    resources:
        **rule_resources("coarse_solver"),
    params:
        **config_keys("coarse.solver", "solver"),
    script:
        "../scripts/coarse_solver.py"


rule coarse_eval:
    input:
        models=[paths.coarse_model(loss) for loss in coarse_losses()],
        solver=paths.coarse_proposals("solver"),
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
        similarity=per_scene(paths.coarse_target(), benchmark_scenes()),
    output:
        proposals=[paths.coarse_proposals(loss) for loss in coarse_losses()],
        table=paths.table("coarse_localization"),
        markdown=paths.table("coarse_localization", "md"),
        rows_markdown=paths.table("coarse_localization_rows", "md"),
        latex=paths.table("coarse_localization", "tex"),
    log:
        "logs/coarse_eval/all.log",
    benchmark:
        "logs/benchmarks/coarse_eval/all.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("coarse_eval")
    resources:
        **rule_resources("coarse_eval"),
    params:
        **config_keys("coarse.losses", "coarse.seed_offset", "seed"),
    script:
        "../scripts/coarse_eval.py"
