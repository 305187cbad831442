# Report figures: training curves, fine error CDFs and Fig. 8, a coarse-score heat map.
# Captions in workflow/report/; `snakemake --report results/report.html` collects them.


include: "inputs/report.smk"


rule figures_training:
    input:
        coarse=expand("results/coarse/{loss}/training.parquet", loss=coarse_losses()),
        fine=[f"results/fine/models/{m}_{t}_{r}/history.parquet" for m, t, r in fine_trained_models()],
    output:
        png=report("results/figures/training_curves.png", caption="../report/training_curves.rst", category="Training"),
    log:
        "logs/figures_training/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("figures_training")
    resources:
        **rule_resources("figures_training"),
    params:
        coarse_labels=coarse_losses(),
        fine_labels=[
            f"{m} ({t} maps, {'GT-BB' if r == 'gtbb' else 'coarse'} training)" for m, t, r in fine_trained_models()
        ],
    script:
        "../scripts/figures_training.py"


rule figures_fine_errors:
    input:
        errors=expand("results/fine/{run}/errors.parquet", run=fine_runs()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
    output:
        cdf=report(
            "results/figures/fine_error_cdf.png", caption="../report/fine_error_cdf.rst", category="Fine localization"
        ),
        vs_objects=report(
            "results/figures/fine_error_vs_objects.png",
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
        models=expand("results/coarse/{loss}/model.pt", loss=coarse_losses()),
        reference_map="results/{scene}/maps/reference_map.parquet",
        queries="results/{scene}/queries/queries.parquet",
        similarity="results/{scene}/coarse/target.parquet",
    output:
        png=report(
            "results/figures/coarse_scores_{scene}.png",
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
        losses=coarse_losses(),
        map_type=config["report"]["heatmap_map_type"],
    script:
        "../scripts/figures_coarse_heatmap.py"


rule query_figures:
    input:
        reference_map="results/{scene}/maps/reference_map.parquet",
        queries="results/{scene}/queries/queries.parquet",
        errors=expand("results/fine/{run}/errors.parquet", run=fine_runs()),
    output:
        figures=report(
            directory("results/{scene}/queries/figures"),
            patterns=["{token}.png"],
            caption="../report/query_figures.rst",
            category="Queries",
            subcategory="scene {scene}",
            labels={"scene": "{scene}", "query": "{token}"},
        ),
        worst=report(
            "results/{scene}/queries/worst_queries.png",
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
            "results/{scene}/maps/viewer.html",
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
