# Queries: recover ground truth by registration, then metric local maps and the split.


rule recover:
    input:
        unpack(scene_data_inputs),
        ingest="results/{scene}/ingest/ingest.json",
    output:
        recovered="results/{scene}/queries/recovered.parquet",
    log:
        "logs/recover/{scene}.log",
    benchmark:
        "benchmarks/recover/{scene}.tsv"
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        root=str(FLAT_ROOT),
        tol_m=config["recover"]["tol_m"],
    script:
        "../scripts/recover.py"


rule queries:
    input:
        unpack(scene_data_inputs),
        recovered="results/{scene}/queries/recovered.parquet",
        reference_map="results/{scene}/maps/reference_map.parquet",
    output:
        queries="results/{scene}/queries/queries.parquet",
    log:
        "logs/queries/{scene}.log",
    benchmark:
        "benchmarks/queries/{scene}.tsv"
    wildcard_constraints:
        scene=PUBLISHED_SCENE,
    conda:
        "../../envs/flatlandia.yaml"
    params:
        root=str(FLAT_ROOT),
        seed=config["seed"],
        split=config["split"],
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
        "../../envs/flatlandia.yaml"
    params:
        city=scene_city,
    script:
        "../scripts/plot_reference_map.py"
