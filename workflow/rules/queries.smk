# Queries: recover ground truth by registration, then metric local maps and the split.


rule recover:
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    input:
        unpack(scene_data_inputs),
        ingest="results/{scene}/ingest/ingest.json",
    output:
        recovered="results/{scene}/queries/recovered.parquet",
    params:
        root=str(FLAT_ROOT),
        tol_m=config["recover"]["tol_m"],
    log:
        "logs/recover/{scene}.log",
    benchmark:
        "benchmarks/recover/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/recover.py"


rule queries:
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    input:
        unpack(scene_data_inputs),
        recovered="results/{scene}/queries/recovered.parquet",
        reference_map="results/{scene}/maps/reference_map.parquet",
    output:
        queries="results/{scene}/queries/queries.parquet",
    params:
        root=str(FLAT_ROOT),
        seed=config["seed"],
        split=config["split"],
    log:
        "logs/queries/{scene}.log",
    benchmark:
        "benchmarks/queries/{scene}.tsv"
    conda:
        "../../envs/flatlandia.yaml"
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
    params:
        city=scene_city,
    log:
        "logs/plot_reference_map/{scene}.log",
    conda:
        "../../envs/flatlandia.yaml"
    script:
        "../scripts/plot_reference_map.py"
