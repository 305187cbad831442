# Input functions of the rules in rules/ablations.smk (kept apart: Snakemake's linter wants rules and
# functions in separate files). No lambdas in rules.


def ablation_runs():
    """The ablation runs (config fine.runs.ablations), each after the run it ablates
    (vocabulary.ablated_run), without repeats."""
    runs = []
    for run in config["fine"]["runs"]["ablations"]:
        runs += [r for r in (vocabulary.ablated_run(run), run) if r and r not in runs]
    return runs


def ablations_table_inputs(wildcards=None):
    """The runs' summaries, and the scene rows of the sequence and fix protocol with the camera
    prior on and off."""
    return {
        "summaries": run_files(ablation_runs(), "summary.json"),
        "beyond": [paths.beyond_scene(prior) for prior in ("on", "off")] if benchmark_scenes() else [],
    }


def ablation_products():
    """The `ablations` target: the ablations' table (results/tables/ablations.md, its data in
    ablations.parquet and ablations_one_frame.parquet)."""
    if not benchmark_scenes():
        return []
    return [paths.table("ablations"), paths.table("ablations_one_frame"), paths.table("ablations", "md")]
