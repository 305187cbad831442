# Queries: recover ground truth by registration (published scenes), then metric local maps and the split.


include: "inputs/queries.smk"


rule recover:
    input:
        unpack(scene_data_inputs),
        ingest="results/{scene}/ingest/ingest.json",
    output:
        recovered="results/{scene}/queries/recovered.parquet",
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
        root=str(FLAT_ROOT),
        tol_m=config["recover"]["tol_m"],
    script:
        "../scripts/recover.py"


rule queries:
    input:
        unpack(queries_inputs),
    output:
        queries="results/{scene}/queries/queries.parquet",
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
        source=scene_source,
        root=str(FLAT_ROOT),
        seed=config["seed"],
        split=config["split"],
        images=queries_images_params,
    script:
        "../scripts/queries.py"


rule plot_reference_map:
    input:
        reference_map="results/{scene}/maps/reference_map.parquet",
        queries="results/{scene}/queries/queries.parquet",
    output:
        png=report(
            "results/{scene}/maps/reference_map.png",
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
