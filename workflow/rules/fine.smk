# Fine 3DoF localization: the geometric solver (`solver`) and the paper's learned baselines
# (mlp, mlp_att, gat, gat_att) on GT/depth local maps x proposals (GT-BB, whole map, coarse), test split.
# A learned model trains per (model x map type x training proposals): gtbb (the paper's), or coarse
# (simulated coarse proposals, for the runs evaluated on real coarse proposals; fine.coarse_training).
# Runs come from config fine.runs (no lambdas in rules).


include: "inputs/fine.smk"


rule fine_train:
    input:
        unpack(fine_train_inputs),
    output:
        checkpoint="results/fine/models/{model}_{map_type}_{train}/checkpoint.pt",
        history="results/fine/models/{model}_{map_type}_{train}/history.parquet",
    log:
        "logs/fine_train/{model}_{map_type}_{train}.log",
    benchmark:
        "logs/benchmarks/fine_train/{model}_{map_type}_{train}.tsv"
    wildcard_constraints:
        model="|".join(FINE_MODELS),
        map_type="gt|depth",
        train="gtbb|coarse",
    priority: fine_train_priority
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fine_train")
    resources:
        **rule_resources("fine_train"),
    params:
        model=fine_model_name,
        train=fine_train_params,
        coarse_training=config["fine"]["coarse_training"],
    script:
        "../scripts/fine_train.py"


rule fine_eval:
    input:
        unpack(fine_eval_inputs),
    output:
        errors="results/fine/{method}_{map_type}_{proposal}/errors.parquet",
        summary="results/fine/{method}_{map_type}_{proposal}/summary.json",
    log:
        "logs/fine_eval/{method}_{map_type}_{proposal}.log",
    benchmark:
        "logs/benchmarks/fine_eval/{method}_{map_type}_{proposal}.tsv"
    wildcard_constraints:
        method="solver|solver-noprior|" + "|".join(FINE_MODELS),
        map_type="gt|depth",
        proposal="gtbb|whole|" + "|".join(FINE_COARSE),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fine_eval")
    resources:
        **rule_resources("fine_eval"),
    params:
        p=fine_eval_params,
        solver=fine_eval_solver,
    script:
        "../scripts/fine_eval.py"


rule fine_table:
    input:
        summaries=expand("results/fine/{run}/summary.json", run=fine_runs()),
        errors=expand("results/fine/{run}/errors.parquet", run=fine_runs()),
    output:
        parquet="results/tables/fine_localization.parquet",
        per_scene="results/tables/fine_per_scene.parquet",
        per_scene_markdown="results/tables/fine_per_scene.md",
        markdown="results/tables/fine_localization.md",
        rows_markdown="results/tables/fine_localization_rows.md",
        latex="results/tables/fine_localization.tex",
    log:
        "logs/fine_table/all.log",
    benchmark:
        "logs/benchmarks/fine_table/all.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fine_table")
    resources:
        **rule_resources("fine_table"),
    script:
        "../scripts/fine_table.py"


rule scene_localization:
    input:
        unpack(scene_localization_inputs),
    output:
        parquet="results/{scene}/localization/localization.parquet",
        markdown="results/{scene}/localization/localization.md",
    log:
        "logs/scene_localization/{scene}.log",
    benchmark:
        "logs/benchmarks/scene_localization/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("scene_localization")
    resources:
        **rule_resources("scene_localization"),
    params:
        map_types=config["fine"]["runs"]["map_types"],
        solver=config["solver"],
    script:
        "../scripts/scene_localization.py"
