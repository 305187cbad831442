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
        checkpoint=paths.fine_model(),
        history=paths.fine_model(part="history.parquet"),
    log:
        "logs/fine_train/{model}_{map_type}_{train}.log",
    benchmark:
        "logs/benchmarks/fine_train/{model}_{map_type}_{train}.tsv"
    wildcard_constraints:
        model="|".join(vocabulary.LEARNED_METHODS),
        train="|".join(vocabulary.TRAIN_REGIMES),
    priority: fine_train_priority
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fine_train")
    resources:
        **rule_resources("fine_train"),
    params:
        **config_keys("fine.train", "fine.train_overrides.{model}", "fine.coarse_training"),
        model=fine_model_name,
    script:
        "../scripts/fine_train.py"


rule fine_eval:
    input:
        unpack(fine_eval_inputs),
    output:
        errors=paths.fine_run(),
        summary=paths.fine_run(part="summary.json"),
    log:
        "logs/fine_eval/{method}_{map_type}_{proposal}.log",
    benchmark:
        "logs/benchmarks/fine_eval/{method}_{map_type}_{proposal}.tsv"
    wildcard_constraints:
        method="|".join(vocabulary.METHODS),
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("fine_eval")
    resources:
        **rule_resources("fine_eval"),
    params:
        **config_keys(
            "solver",
            "fine.coarse_strategy",
            "coarse.solver.fine_strategy",
            "fine.coarse_training.enabled",
            "fine.coarse_training.crop_m",
            reads=fine_eval_reads,
        ),
    script:
        "../scripts/fine_eval.py"


rule fine_table:
    input:
        summaries=run_files(fine_runs(), "summary.json"),
        errors=run_files(fine_runs(), "errors.parquet"),
    output:
        parquet=paths.table("fine_localization"),
        per_scene=paths.table("fine_per_scene"),
        per_scene_markdown=paths.table("fine_per_scene", "md"),
        markdown=paths.table("fine_localization", "md"),
        rows_markdown=paths.table("fine_localization_rows", "md"),
        latex=paths.table("fine_localization", "tex"),
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
        parquet=paths.scene_localization(),
        markdown=paths.scene_localization(ext="md"),
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
        **config_keys("fine.runs.map_types", "solver"),
    script:
        "../scripts/scene_localization.py"
