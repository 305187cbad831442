# Input functions and settings of the rules in rules/report.smk (kept apart: Snakemake's linter
# wants rules and functions in separate files). No lambdas in rules.


def fine_trained_models():
    """(model, map_type, training proposals) of every learned fine run of the config (the solver needs no training)."""
    out = []
    for run in fine_runs():
        method, map_type, proposal = vocabulary.split_run(run)
        key = (method, map_type, fine_train_regime(proposal))
        if method in vocabulary.LEARNED_METHODS and key not in out:  # not the solver, nor an external method
            out.append(key)
    return out


def fine_training_labels():
    """The training curves' legend of each learned model (fine_trained_models' order)."""
    oracle = vocabulary.ORACLE_STRATEGY
    return [
        f"{m} ({t} maps, {oracle if r == vocabulary.GTBB else 'coarse'} training)" for m, t, r in fine_trained_models()
    ]


def heatmap_scene():
    """The scene of the coarse heat map: config report.heatmap_scene, else the first published scene."""
    wanted = str(config["report"]["heatmap_scene"])
    scenes = benchmark_scenes()
    return wanted if wanted in scenes else (scenes[0] if scenes else None)


def report_figures():
    """The benchmark's figures: training, errors, the coarse heat map, and per benchmark scene a
    figure per test query and a gallery of its worst queries."""
    if not benchmark_scenes():
        return []
    out = [paths.figure(f) for f in ("training_curves.png", "fine_error_cdf.png", "fine_error_vs_objects.png")]
    out += [paths.figure(f"coarse_scores_{heatmap_scene()}.png")]
    return out + [paths.worst_queries(s) for s in benchmark_scenes()]


def scene_viewers():
    """A map viewer per selected scene (those of the benchmark show its runs' estimates)."""
    return [paths.viewer(s) for s in selected_scenes()]


def viewer_runs(wildcards):
    """The fine runs a scene's viewer shows: all of them on a benchmark scene, none elsewhere."""
    return fine_runs() if wildcards.scene in benchmark_scenes() else []


def viewer_inputs(wildcards):
    s = wildcards.scene
    return {
        "reference_map": paths.reference_map(s),
        "queries": paths.queries(s),
        "errors": run_files(viewer_runs(wildcards), "errors.parquet"),
    }
