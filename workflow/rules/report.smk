# Report figures: training curves, fine error CDFs and Fig. 8, a coarse-score heat map.
# Captions in workflow/report/; `snakemake --report results/report.html` collects them.


include: "inputs/report.smk"


rule figures_training:
    input:
        coarse=[paths.coarse_training(loss) for loss in coarse_losses()],
        fine=[paths.fine_model(m, t, r, "history.parquet") for m, t, r in fine_trained_models()],
    output:
        png=report(paths.figure("training_curves.png"), caption="../report/training_curves.rst", category="Training"),
    log:
        "logs/figures_training/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("figures_training")
    resources:
        **rule_resources("figures_training"),
    params:
        **config_keys("coarse.losses"),
        fine_labels=fine_training_labels(),
    script:
        "../scripts/figures_training.py"


rule figures_fine_errors:
    input:
        errors=run_files(fine_runs(), "errors.parquet"),
        queries=per_scene(paths.queries(), benchmark_scenes()),
    output:
        cdf=report(
            paths.figure("fine_error_cdf.png"), caption="../report/fine_error_cdf.rst", category="Fine localization"
        ),
        vs_objects=report(
            paths.figure("fine_error_vs_objects.png"),
            caption="../report/fine_error_vs_objects.rst",
            category="Fine localization",
        ),
    log:
        "logs/figures_fine_errors/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("figures_fine_errors")
    resources:
        **rule_resources("figures_fine_errors"),
    params:
        runs=fine_runs(),
    script:
        "../scripts/figures_fine_errors.py"


rule figures_coarse_heatmap:
    input:
        models=[paths.coarse_model(loss) for loss in coarse_losses()],
        reference_map=paths.reference_map(),
        queries=paths.queries(),
        similarity=paths.coarse_target(),
    output:
        png=report(
            paths.figure("coarse_scores_{scene}.png"),
            caption="../report/coarse_scores.rst",
            category="Coarse localization",
            labels={"scene": "{scene}"},
        ),
    log:
        "logs/figures_coarse_heatmap/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("figures_coarse_heatmap")
    resources:
        **rule_resources("figures_coarse_heatmap"),
    params:
        **config_keys("coarse.losses", "report.heatmap_map_type"),
    script:
        "../scripts/figures_coarse_heatmap.py"


rule query_figures:
    input:
        reference_map=paths.reference_map(),
        queries=paths.queries(),
        errors=run_files(fine_runs(), "errors.parquet"),
    output:
        figures=report(
            directory(paths.query_figures()),
            patterns=["{token}.png"],
            caption="../report/query_figures.rst",
            category="Queries",
            subcategory="scene {scene}",
            labels={"scene": "{scene}", "query": "{token}"},
        ),
        worst=report(
            paths.worst_queries(),
            caption="../report/worst_queries.rst",
            category="Worst queries",
            labels={"scene": "{scene}"},
        ),
    log:
        "logs/query_figures/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("query_figures")
    resources:
        **rule_resources("query_figures"),
    params:
        runs=fine_runs(),
    script:
        "../scripts/query_figures.py"


rule viewer:
    input:
        unpack(viewer_inputs),
    output:
        html=report(
            paths.viewer(),
            caption="../report/viewer.rst",
            category="Map viewer",
            labels={"scene": "{scene}"},
        ),
    log:
        "logs/viewer/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("viewer")
    resources:
        **rule_resources("viewer"),
    params:
        runs=viewer_runs,
        source=scene_source,
    script:
        "../scripts/viewer.py"
