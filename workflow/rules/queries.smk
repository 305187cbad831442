# Queries: recover ground truth by registration (published scenes), then metric local maps and the split.


include: "inputs/queries.smk"


rule recover:
    input:
        unpack(scene_data_inputs),
        ingest=paths.ingest(),
    output:
        recovered=paths.recovered(),
    log:
        "logs/recover/{scene}.log",
    benchmark:
        "logs/benchmarks/recover/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("recover")
    resources:
        **rule_resources("recover"),
    params:
        **config_keys("recover.tol_m"),
        root=str(FLAT_ROOT),
    script:
        "../scripts/recover.py"


rule queries:
    input:
        unpack(queries_inputs),
    output:
        queries=paths.queries(),
    log:
        "logs/queries/{scene}.log",
    benchmark:
        "logs/benchmarks/queries/{scene}.tsv"
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("queries")
    resources:
        **rule_resources("queries"),
    params:
        **config_keys("seed", "split"),
        **config_keys("images.min_objects", "images.min_points", "images.depth", reads=images_scene_reads),
        source=scene_source,
        root=str(FLAT_ROOT),
    script:
        "../scripts/queries.py"


rule plot_reference_map:
    input:
        reference_map=paths.reference_map(),
        queries=paths.queries(),
    output:
        png=report(
            paths.reference_map(ext="png"),
            caption="../report/reference_map.rst",
            category="Reference maps",
            labels={"scene": "{scene}"},
        ),
    log:
        "logs/plot_reference_map/{scene}.log",
    conda:
        "../envs/flatlandia.yaml"
    threads: rule_threads("plot_reference_map")
    resources:
        **rule_resources("plot_reference_map"),
    params:
        city=scene_city,
    script:
        "../scripts/plot_reference_map.py"
