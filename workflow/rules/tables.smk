# Tables over the benchmark scenes (config benchmark_scenes; `select` does not change them).


include: "inputs/tables.smk"


rule dataset_stats:
    input:
        reference_maps=per_scene("results/{scene}/maps/reference_map.parquet", benchmark_scenes()),
        queries=per_scene("results/{scene}/queries/queries.parquet", benchmark_scenes()),
        tokens=tokens_files(),
    output:
        parquet="results/tables/dataset_stats.parquet",
        per_scene="results/tables/dataset_stats_per_scene.parquet",
        markdown=report("results/tables/dataset_stats.md", caption="../report/dataset_stats.rst", category="Tables"),
        latex="results/tables/dataset_stats.tex",
    log:
        "logs/dataset_stats/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("dataset_stats")
    resources:
        **rule_resources("dataset_stats"),
    params:
        cities=benchmark_cities(),
    script:
        "../scripts/dataset_stats.py"


rule recovery_table:
    input:
        recovered=per_scene("results/{scene}/queries/recovered.parquet", benchmark_scenes()),
    output:
        parquet="results/tables/recovery.parquet",
        markdown=report("results/tables/recovery.md", caption="../report/recovery.rst", category="Tables"),
        latex="results/tables/recovery.tex",
    log:
        "logs/recovery_table/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("recovery_table")
    resources:
        **rule_resources("recovery_table"),
    script:
        "../scripts/recovery_table.py"


rule availability_table:
    input:
        reports=per_scene("results/{scene}/ingest/ingest.json", benchmark_scenes()),
    output:
        parquet="results/tables/availability.parquet",
        markdown="results/tables/availability.md",
    log:
        "logs/availability_table/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("availability_table")
    resources:
        **rule_resources("availability_table"),
    script:
        "../scripts/availability_table.py"


rule tables:
    input:
        result_tables(),


# The benchmark's audit snapshot: every artifact with a provenance record (maps included), rebuilt
# when the benchmark's results change; `select` does not change it. `flatlandia audit` reads the
# live records, so it describes any run.
rule manifest:
    input:
        benchmark_products() + report_figures(),
    output:
        parquet="results/manifest.parquet",
    log:
        "logs/manifest/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("manifest")
    resources:
        **rule_resources("manifest"),
    script:
        "../scripts/manifest.py"
