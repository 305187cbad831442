# Coarse map localization (issue 4), draft: neighbourhood similarity per scene -> one GAT per loss
# (Sim | Trip | Sim+Trip) over every scene's train split -> proposals (N_LM | 2N_LM | R_30 | GT-BB)
# and Table 3 on the test split. Needs `include: "workflow/rules/coarse.smk"` in the Snakefile
# (after common.smk) and a `coarse:` section as in config/coarse.example.yaml. No lambdas in rules.

COARSE_LOSSES = ["sim", "trip", "simtrip"]


def coarse_cfg():
    return config.get("coarse", {})


def coarse_losses():
    return coarse_cfg().get("losses", COARSE_LOSSES)


def coarse_train_params(wildcards):
    """coarse.train with the seed derived from the master seed (config seed + coarse.seed_offset)."""
    train = dict(coarse_cfg().get("train", {}))
    train["seed"] = int(config.get("seed", 0)) + int(coarse_cfg().get("seed_offset", 0))
    return train


def coarse_eval_seed(wildcards):
    return int(config.get("seed", 0)) + int(coarse_cfg().get("seed_offset", 0))


def coarse_eval_losses(wildcards):
    return coarse_losses()


rule coarse_similarity:
    input:
        reference_map="results/{scene}/maps/reference_map.parquet",
        queries="results/{scene}/queries/queries.parquet",
    output:
        similarity="results/{scene}/coarse/similarity.parquet",
    params:
        similarity=coarse_cfg().get("similarity", {}),
    threads: 1
    log:
        "logs/coarse_similarity/{scene}.log",
    benchmark:
        "benchmarks/coarse_similarity/{scene}.tsv"
    resources:
        mem_mb=2000,
        runtime=10,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/coarse_similarity.py"


rule coarse_train:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet"),
        queries=per_scene("results/{scene}/queries/queries.parquet"),
        similarity=per_scene("results/{scene}/coarse/similarity.parquet"),
    output:
        model="results/coarse/{loss}/model.pt",
        history="results/coarse/{loss}/training.parquet",
    params:
        train=coarse_train_params,
    wildcard_constraints:
        loss="|".join(COARSE_LOSSES),
    threads: 1
    log:
        "logs/coarse_train/{loss}.log",
    benchmark:
        "benchmarks/coarse_train/{loss}.tsv"
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/coarse_train.py"


rule coarse_eval:
    input:
        models=expand("results/coarse/{loss}/model.pt", loss=coarse_losses()),
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet"),
        queries=per_scene("results/{scene}/queries/queries.parquet"),
        similarity=per_scene("results/{scene}/coarse/similarity.parquet"),
    output:
        proposals=expand("results/coarse/{loss}/proposals.parquet", loss=coarse_losses()),
        table="results/tables/coarse_localization.parquet",
        markdown="results/tables/coarse_localization.md",
    params:
        losses=coarse_eval_losses,
        seed=coarse_eval_seed,
    threads: 1
    log:
        "logs/coarse_eval/all.log",
    benchmark:
        "benchmarks/coarse_eval/all.tsv"
    resources:
        mem_mb=4000,
        runtime=20,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/coarse_eval.py"
