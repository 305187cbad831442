# Coarse map localization: the neighbourhood similarity target per scene -> one GAT per loss
# (Sim | Trip | Sim+Trip) over every scene's train split -> proposals (N_LM | 2N_LM | R_30 | GT-BB)
# and Table 3 on the test split; beside them the training-free proposals of the geometric solver
# (coarse_solver, rows "Solver" of Table 3). Settings: the `coarse:` section of config/config.yaml
# (a short default run); config/paper.yaml has the paper's 800 epochs. No lambdas in rules.


include: "inputs/coarse.smk"


rule coarse_target:
    input:
        reference_map="results/{scene}/maps/reference_map.parquet",
        queries="results/{scene}/queries/queries.parquet",
    output:
        similarity="results/{scene}/coarse/target.parquet",
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
        similarity=config["coarse"]["similarity"],
    script:
        "../scripts/coarse_target.py"


rule coarse_train:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
        similarity=per_scene("results/{scene}/coarse/target.parquet", benchmark_scenes()),
    output:
        model="results/coarse/{loss}/model.pt",
        history="results/coarse/{loss}/training.parquet",
    log:
        "logs/coarse_train/{loss}.log",
    benchmark:
        "logs/benchmarks/coarse_train/{loss}.tsv"
    wildcard_constraints:
        loss="|".join(COARSE_LOSSES),
    priority: 1
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("coarse_train")
    resources:
        **rule_resources("coarse_train"),
    params:
        train=COARSE_TRAIN,
    script:
        "../scripts/coarse_train.py"


rule coarse_solver:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
        solver_priors="results/solver/priors/scale.json",
    output:
        proposals="results/coarse/solver/proposals.parquet",
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
        proposals=config["coarse"]["solver"],
        solver=config["solver"],
    script:
        "../scripts/coarse_solver.py"


rule coarse_eval:
    input:
        models=expand("results/coarse/{loss}/model.pt", loss=coarse_losses()),
        solver="results/coarse/solver/proposals.parquet",
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
        similarity=per_scene("results/{scene}/coarse/target.parquet", benchmark_scenes()),
    output:
        proposals=expand("results/coarse/{loss}/proposals.parquet", loss=coarse_losses()),
        table="results/tables/coarse_localization.parquet",
        markdown="results/tables/coarse_localization.md",
        rows_markdown="results/tables/coarse_localization_rows.md",
        latex="results/tables/coarse_localization.tex",
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
        losses=coarse_losses(),
        seed=COARSE_SEED,
    script:
        "../scripts/coarse_eval.py"
