# Tables over the benchmark scenes (config benchmark_scenes; `select` does not change them).


include: "inputs/tables.smk"


rule dataset_stats:
    input:
        reference_maps=per_scene(paths.reference_map(), benchmark_scenes()),
        queries=per_scene(paths.queries(), benchmark_scenes()),
        tokens=tokens_files(),
    output:
        parquet=paths.table("dataset_stats"),
        per_scene=paths.BENCHMARK_RECORD,
        markdown=report(paths.table("dataset_stats", "md"), caption="../report/dataset_stats.rst", category="Tables"),
        latex=paths.table("dataset_stats", "tex"),
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
        recovered=per_scene(paths.recovered(), benchmark_scenes()),
    output:
        parquet=paths.table("recovery"),
        markdown=report(paths.table("recovery", "md"), caption="../report/recovery.rst", category="Tables"),
        latex=paths.table("recovery", "tex"),
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
        reports=per_scene(paths.ingest(), benchmark_scenes()),
    output:
        parquet=paths.table("availability"),
        markdown=paths.table("availability", "md"),
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
        parquet=paths.manifest(),
    log:
        "logs/manifest/all.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("manifest")
    resources:
        **rule_resources("manifest"),
    script:
        "../scripts/manifest.py"
