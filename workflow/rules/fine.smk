# Fine 3DoF localization (issue 6): the geometric solver (`geo`) and the paper's learned baselines
# (mlp, mlp_att, gat, gat_att) on GT/depth local maps x proposals (GT-BB, whole map, coarse), test split.
# Runs come from config fine.runs; helpers here, no lambdas in rules.

FINE_MODELS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
FINE_COARSE = {"coarse-sim": "Sim", "coarse-trip": "Trip", "coarse-simtrip": "Sim+Trip"}


def fine_cfg():
    return config.get("fine", {})


def fine_runs():
    """Run names {method}_{map_type}_{proposal} from config fine.runs (methods x map types x proposals)."""
    runs = fine_cfg().get("runs", {})
    grid = [f"{m}_{t}_{p}" for m in runs.get("methods", ["geo"]) for t in runs.get("map_types", ["gt", "depth"])
            for p in runs.get("proposals", ["gtbb"])]
    return grid + [r for r in runs.get("extra", []) if r not in grid]


def fine_eval_inputs(wildcards):
    inp = {"reference_maps": per_scene("results/{scene}/maps/reference_map.parquet"),
           "queries": per_scene("results/{scene}/queries/queries.parquet")}
    if wildcards.method != "geo":
        inp["checkpoint"] = f"results/fine/models/{wildcards.method}_{wildcards.map_type}/checkpoint.pt"
    if wildcards.proposal in FINE_COARSE:
        loss = wildcards.proposal.split("-", 1)[1]
        inp["coarse"] = f"results/coarse/{loss}/proposals.parquet"
    return inp


def fine_eval_params(wildcards):
    p = wildcards.proposal
    strategy = fine_cfg().get("coarse_strategy", "2N_LM")
    label = {"gtbb": "GT-BB", "whole": "whole map"}.get(p, f"{FINE_COARSE.get(p, p)} {strategy}")
    return {"method": wildcards.method, "proposal": p, "strategy": strategy, "strategy_label": label}


def fine_model_name(wildcards):
    return FINE_MODELS[wildcards.model]


def fine_train_params(wildcards):
    """fine.train, updated by fine.train_overrides[{model}] (e.g. fewer epochs for the slower GATs)."""
    return {**fine_cfg().get("train", {}), **fine_cfg().get("train_overrides", {}).get(wildcards.model, {})}


rule fine_train:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet"),
        queries=per_scene("results/{scene}/queries/queries.parquet"),
    output:
        checkpoint="results/fine/models/{model}_{map_type}/checkpoint.pt",
        history="results/fine/models/{model}_{map_type}/history.parquet",
    params:
        model=fine_model_name,
        train=fine_train_params,
    wildcard_constraints:
        model="|".join(FINE_MODELS),
        map_type="gt|depth",
    threads: 1
    log:
        "logs/fine_train/{model}_{map_type}.log",
    benchmark:
        "benchmarks/fine_train/{model}_{map_type}.tsv"
    resources:
        mem_mb=4000,
        runtime=120,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fine_train.py"


rule fine_eval:
    input:
        unpack(fine_eval_inputs),
    output:
        errors="results/fine/{method}_{map_type}_{proposal}/errors.parquet",
        summary="results/fine/{method}_{map_type}_{proposal}/summary.json",
    params:
        p=fine_eval_params,
        geo=fine_cfg().get("geo", {}),
    wildcard_constraints:
        method="geo|" + "|".join(FINE_MODELS),
        map_type="gt|depth",
        proposal="gtbb|whole|" + "|".join(FINE_COARSE),
    threads: 1
    log:
        "logs/fine_eval/{method}_{map_type}_{proposal}.log",
    benchmark:
        "benchmarks/fine_eval/{method}_{map_type}_{proposal}.tsv"
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fine_eval.py"


rule fine_table:
    input:
        summaries=expand("results/fine/{run}/summary.json", run=fine_runs()),
    output:
        parquet="results/tables/fine_localization.parquet",
        markdown="results/tables/fine_localization.md",
    log:
        "logs/fine_table/all.log",
    benchmark:
        "benchmarks/fine_table/all.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fine_table.py"
