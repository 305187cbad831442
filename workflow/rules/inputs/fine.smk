import math

# Input functions and settings of the rules in rules/fine.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


#: the geometric solver's methods: with the training split's cameras, and without them (the camera
#: prior off for that run: what the whole-map figures owe to the cameras)
SOLVER_METHODS = ["solver", "solver-noprior"]
FINE_MODELS = {"mlp": "MLP", "mlp_att": "MLP+ATT", "gat": "GAT", "gat_att": "GAT+ATT"}
FINE_COARSE = {"coarse-sim": "Sim", "coarse-trip": "Trip", "coarse-simtrip": "Sim+Trip", "coarse-solver": "Solver"}


def _external_methods():
    from flatlandia import score
    from flatlandia.config import ConfigError

    try:
        return score.external_entries(config["external"])
    except ConfigError as err:
        sys.exit(f"ERROR: config: {err}")


EXTERNAL_METHODS = _external_methods()


def external_methods():
    """Config external, each entry with its defaults (map_types, proposals) filled in."""
    return EXTERNAL_METHODS


def external_runs():
    """The external methods' runs {name}_{map_type}_{proposal} (rule external_eval scores them)."""
    return [f"{e['name']}_{t}_{p}" for e in external_methods() for t in e["map_types"] for p in e["proposals"]]


def fine_runs():
    """Run names {method}_{map_type}_{proposal} from config fine.runs (methods x map types x proposals),
    then the external methods' runs (config external)."""
    runs = config["fine"]["runs"]
    grid = [f"{m}_{t}_{p}" for m in runs["methods"] for t in runs["map_types"] for p in runs["proposals"]]
    return grid + [r for r in runs["extra"] if r not in grid] + external_runs()


def fine_eval_inputs(wildcards):
    inp = {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        "queries": per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
    }
    if wildcards.method not in SOLVER_METHODS:
        regime = fine_train_regime(wildcards.proposal)
        inp["checkpoint"] = f"results/fine/models/{wildcards.method}_{wildcards.map_type}_{regime}/checkpoint.pt"
    elif wildcards.map_type == "depth":  # without cameras no verifier: the scale prior alone
        inp["solver_priors"] = solver_priors_file(wildcards.proposal if wildcards.method == "solver" else "scale")
    if wildcards.proposal in FINE_COARSE:
        loss = wildcards.proposal.split("-", 1)[1]
        inp["coarse"] = f"results/coarse/{loss}/proposals.parquet"
    return inp


def fine_train_regime(proposal):
    """Training proposals of the learned model a run evaluates: ``coarse`` (simulated coarse
    proposals) for runs on coarse proposals when fine.coarse_training.enabled, else ``gtbb``; the
    solver's box proposals (strategy BB) are what the GT-BB-trained model knows (on them it is
    7.2 m against 10.5 m for the coarse-trained one, depth maps, validation split)."""
    on = config["fine"]["coarse_training"]["enabled"]
    box = fine_coarse_strategy(proposal) == "BB"
    return "coarse" if proposal in FINE_COARSE and on and not box else "gtbb"


def fine_coarse_strategy(proposal):
    """The strategy of a coarse proposal table that feeds the fine runs: coarse.solver.fine_strategy
    for the solver's proposals (the box the learned models train on), fine.coarse_strategy otherwise."""
    if proposal == "coarse-solver":
        return config["coarse"]["solver"]["fine_strategy"]
    return config["fine"]["coarse_strategy"]


def fine_eval_params(wildcards):
    """What rule fine_eval reads for one run, and only that (the provenance record lists these as
    the run's settings): the coarse table's strategy for coarse proposals; how a learned model was
    trained (``train_regime``, and ``crop_m`` for coarse training), not for the solver."""
    p = wildcards.proposal
    out = {"method": wildcards.method, "proposal": p}
    if p in FINE_COARSE:
        out["strategy"] = fine_coarse_strategy(p)
    out["strategy_label"] = {"gtbb": "GT-BB", "whole": "whole map"}.get(p) or f"{FINE_COARSE[p]} {out['strategy']}"
    if wildcards.method not in SOLVER_METHODS:
        out["train_regime"] = fine_train_regime(p)
        if out["train_regime"] == "coarse":
            out["crop_m"] = float(config["fine"]["coarse_training"]["crop_m"])
    return out


def fine_eval_solver(wildcards):
    """The solver's settings, for the solver's runs only (a learned model reads none of them)."""
    return config["solver"] if wildcards.method in SOLVER_METHODS else {}


#: the order of ready trainings: the longest first (a clean default run: GAT+ATT 110 s, GAT 85 s,
#: MLP+ATT 56 s, MLP 31-37 s), ahead of the evaluations and figures, so the run does not end on one
#: long training with the other core idle (it did: 35 s idle before the last evaluations)
FINE_TRAIN_PRIORITY = {"gat_att": 4, "gat": 3, "mlp_att": 2, "mlp": 1}


#: CPU seconds per training epoch on one core at the paper's sizes (config/paper.yaml; the default
#: sizes are smaller and faster), measured by benchmarks/bench_paper_config.py on the benchmark
#: scenes' GT-BB training samples; training on simulated coarse proposals takes about twice as long
FINE_EPOCH_S = {"mlp": 0.26, "mlp_att": 1.3, "gat": 12.2, "gat_att": 13.6}


def fine_train_runtime(wildcards):
    """A fine_train job's runtime bound in minutes (the cluster's time limit): its epochs at the
    paper sizes' speed, x2 on coarse proposals, x1.5 for a slower node, plus 10 minutes."""
    epochs = fine_train_params(wildcards)["epochs"]
    slow = 2.0 if wildcards.train == "coarse" else 1.0
    return int(math.ceil(epochs * FINE_EPOCH_S[wildcards.model] * slow * 1.5 / 60)) + 10


def fine_eval_gpus(wildcards):
    """GPUs for a fine_eval job with config device: cuda (rules/resources.yaml): 1 for a learned
    model's run, none for the solver's (no model)."""
    return 1 if wildcards.method in FINE_MODELS else 0


def fine_train_priority(wildcards):
    return FINE_TRAIN_PRIORITY.get(wildcards.model, 1)


def fine_model_name(wildcards):
    return FINE_MODELS[wildcards.model]


def fine_train_params(wildcards):
    """fine.train, updated by fine.train_overrides[{model}] (e.g. fewer epochs for the slower GATs),
    and for training on simulated coarse proposals by fine.coarse_training.epochs."""
    p = {**config["fine"]["train"], **config["fine"]["train_overrides"][wildcards.model]}
    epochs = config["fine"]["coarse_training"]["epochs"]
    if wildcards.train == "coarse" and epochs:
        p["epochs"] = epochs
    return p


def fine_train_inputs(wildcards):
    """The benchmark scenes' maps and queries; for training on simulated coarse proposals with
    fine.coarse_training.warm_start, the GT-BB-trained model it starts from."""
    inp = {
        "reference_maps": per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        "queries": per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
    }
    if wildcards.train == "coarse" and config["fine"]["coarse_training"]["warm_start"]:
        inp["init"] = f"results/fine/models/{wildcards.model}_{wildcards.map_type}_gtbb/checkpoint.pt"
    return inp


def scene_localization_inputs(wildcards):
    """An images scene's map and queries, and the benchmark's gtbb checkpoints of the learned
    methods of fine.runs (no retraining on the scene)."""
    s = wildcards.scene
    runs = config["fine"]["runs"]
    return {
        "reference_map": f"results/{s}/maps/reference_map.parquet",
        "queries": f"results/{s}/queries/queries.parquet",
        "checkpoints": [
            f"results/fine/models/{m}_{t}_gtbb/checkpoint.pt"
            for m in runs["methods"]
            if m not in SOLVER_METHODS
            for t in runs["map_types"]
        ],
    }
