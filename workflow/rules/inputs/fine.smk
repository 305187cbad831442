import math

from flatlandia.proposals import training_settings

# Input functions and settings of the rules in rules/fine.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def _external_methods():
    from flatlandia import score
    from flatlandia.config import ConfigError

    try:
        entries = score.external_entries(config["external"])
    except ConfigError as err:
        sys.exit(f"ERROR: config: {err}")
    for k, e in enumerate(entries):  # a missing poses file left the method out of every table, status 0
        if not config_path(e["poses"]).is_file():
            sys.exit(
                f"ERROR: config: 'external.{k}.poses': {e['poses']!r} is not a file (relative to the working "
                "folder, else to the repository): the poses of method " + repr(e["name"])
            )
    return entries


EXTERNAL_METHODS = _external_methods()


def external_methods():
    """Config external, each entry with its defaults (map_types, proposals) filled in."""
    return EXTERNAL_METHODS


def external_runs():
    """The external methods' runs {name}_{map_type}_{proposal} (rule external_eval scores them)."""
    return [
        vocabulary.run_name(e["name"], t, p) for e in external_methods() for t in e["map_types"] for p in e["proposals"]
    ]


def fine_runs():
    """Run names {method}_{map_type}_{proposal} from config fine.runs (methods x map types x proposals),
    then the external methods' runs (config external); paths.run_file finds each run's files."""
    runs = config["fine"]["runs"]
    grid = [vocabulary.run_name(m, t, p) for m in runs["methods"] for t in runs["map_types"] for p in runs["proposals"]]
    return grid + [r for r in runs["extra"] if r not in grid] + external_runs()


def run_files(runs, part):
    """The files ``part`` (errors.parquet, summary.json) of fine runs, built-in and external."""
    return [paths.run_file(run, part) for run in runs]


def fine_eval_inputs(wildcards):
    method, proposal = wildcards.method, wildcards.proposal
    inp = {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
    }
    if method in vocabulary.LEARNED_METHODS:
        inp["checkpoint"] = paths.fine_model(method, wildcards.map_type, fine_train_regime(proposal))
    elif wildcards.map_type == "depth":  # without cameras no verifier: the scale prior alone
        inp["solver_priors"] = paths.proposal_priors(proposal) if method == "solver" else paths.solver_priors("scale")
    if vocabulary.coarse_source(proposal):
        inp["coarse"] = paths.proposal_table(proposal)
    return inp


def fine_train_regime(proposal):
    """Training proposals of the learned model a run evaluates (vocabulary.train_regime): ``coarse``
    (simulated coarse proposals) for runs on coarse proposals when fine.coarse_training.enabled, else
    ``gtbb``; the solver's box proposals (strategy BB) are what the GT-BB-trained model knows (on them
    it beats the coarse-trained one: docs/measurements.md, "Training-free coarse proposals")."""
    strategy = vocabulary.coarse_strategy(proposal, config)
    return vocabulary.train_regime(proposal, strategy, config["fine"]["coarse_training"]["enabled"])


def fine_eval_reads(wildcards):
    """The config keys one fine_eval job reads (the others of its config_keys are {} for it): the
    solver's settings for the solver's runs; the strategy key of a coarse proposal
    (vocabulary.strategy_key); for a learned model on coarse proposals whether it was trained on
    them, and if so the radius its proposals are cut to."""
    method, proposal = wildcards.method, wildcards.proposal
    keys = {"solver"} if method in vocabulary.SOLVER_METHODS else set()
    if vocabulary.strategy_key(proposal):
        keys.add(vocabulary.strategy_key(proposal))
        if method in vocabulary.LEARNED_METHODS:
            keys.add("fine.coarse_training.enabled")
            if fine_train_regime(proposal) == "coarse":
                keys.add("fine.coarse_training.crop_m")
    return keys


def strategy_reads(wildcards):
    """The strategy key of a coarse proposal (external_eval reads nothing else of the config)."""
    key = vocabulary.strategy_key(wildcards.proposal)
    return {key} if key else set()


#: the order of ready trainings: the longest first, ahead of the evaluations and figures, so the run
#: does not end on one long training with the other core idle (it did: docs/measurements.md,
#: "Code paths")
FINE_TRAIN_PRIORITY = {"gat_att": 4, "gat": 3, "mlp_att": 2, "mlp": 1}


#: CPU seconds per training epoch on one core at the paper's sizes (config/paper.yaml; the default
#: sizes are smaller and faster), measured by benchmarks/bench_paper_config.py on the benchmark
#: scenes' GT-BB training samples; training on simulated coarse proposals takes about twice as long
FINE_EPOCH_S = {"mlp": 0.26, "mlp_att": 1.3, "gat": 12.2, "gat_att": 13.6}


def fine_train_runtime(wildcards):
    """A fine_train job's runtime bound in minutes (the cluster's time limit): its epochs at the
    paper sizes' speed, x2 on coarse proposals, x1.5 for a slower node, plus 10 minutes."""
    fine = config["fine"]
    train = fine["train_overrides"][wildcards.model]
    epochs = training_settings(fine["train"], train, fine["coarse_training"], wildcards.train)["epochs"]
    slow = 2.0 if wildcards.train == "coarse" else 1.0
    return int(math.ceil(epochs * FINE_EPOCH_S[wildcards.model] * slow * 1.5 / 60)) + 10


def fine_eval_gpus(wildcards):
    """GPUs for a fine_eval job with config device: cuda (rules/resources.yaml): 1 for a learned
    model's run, none for the solver's (no model)."""
    return 1 if wildcards.method in vocabulary.LEARNED_METHODS else 0


def fine_train_priority(wildcards):
    return FINE_TRAIN_PRIORITY.get(wildcards.model, 1)


def fine_model_name(wildcards):
    return vocabulary.LEARNED_METHODS[wildcards.model]


def fine_train_inputs(wildcards):
    """The benchmark scenes' maps and queries; for training on simulated coarse proposals with
    fine.coarse_training.warm_start, the GT-BB-trained model it starts from."""
    inp = {
        "reference_maps": per_scene(paths.reference_map(), benchmark_scenes()),
        "queries": per_scene(paths.queries(), benchmark_scenes()),
    }
    if wildcards.train == "coarse" and config["fine"]["coarse_training"]["warm_start"]:
        inp["init"] = paths.fine_model(wildcards.model, wildcards.map_type, vocabulary.GTBB)
    return inp


def scene_localization_inputs(wildcards):
    """An images scene's map and queries, and the benchmark's gtbb checkpoints of the learned
    methods of fine.runs (no retraining on the scene)."""
    s = wildcards.scene
    runs = config["fine"]["runs"]
    return {
        "reference_map": paths.reference_map(s),
        "queries": paths.queries(s),
        "checkpoints": [
            paths.fine_model(m, t, vocabulary.GTBB)
            for m in runs["methods"]
            if m in vocabulary.LEARNED_METHODS
            for t in runs["map_types"]
        ],
    }
