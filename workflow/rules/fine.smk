# Fine 3DoF localization: the geometric bearing solver on the test split.


rule fine_solver:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet"),
        queries=per_scene("results/{scene}/queries/queries.parquet"),
    output:
        errors="results/fine/solver_{map_type}_{proposal}/errors.parquet",
        summary="results/fine/solver_{map_type}_{proposal}/summary.json",
    params:
        solver=config["fine"]["solver"],
    log:
        "logs/fine_solver/{map_type}_{proposal}.log",
    benchmark:
        "benchmarks/fine_solver/{map_type}_{proposal}.tsv"
    resources:
        mem_mb=4000,
        runtime=60,
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fine_solver.py"


rule fine_solver_table:
    input:
        summaries=fine_solver_summaries(),
    output:
        parquet="results/tables/fine_solver.parquet",
        markdown=report("results/tables/fine_solver.md", caption="../report/fine_solver.rst", category="Tables"),
        latex="results/tables/fine_solver.tex",
    log:
        "logs/fine_solver_table/all.log",
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/fine_solver_table.py"
